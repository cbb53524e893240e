"""A digest of every compose service's outputs on a scenario, to show that a refactor changed none of them.

For each ``fixstream run <service>`` of ``compose.yaml`` (the recorder aside): the service, configured as compose
configures it, runs the scenario's events offline (:func:`tools.report.offline.service_outputs`: its own decode,
dispatch and stamping) and every output (fixes, tracks, verdicts, replies, diagnostics) goes into a SHA-256 of its
key and its encoded bytes, in order. Run it in two checkouts and compare::

    python -m bench.outputs_digest scenarios/demo.yaml > before.txt     # in the old tree
    python -m bench.outputs_digest scenarios/demo.yaml > after.txt      # in the new tree
    diff before.txt after.txt && echo identical

(``PYTHONPATH=<tree>`` with one virtual environment works: the tree on the path wins over the editable install.)
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

from services.player.scenario import load_scenario
from shared import codec
from tools.report.offline import scenario_feed, service_outputs
from tools.stack import load_compose


def digests(scenario: Path, compose_file: Path = Path("compose.yaml")) -> dict[str, tuple[int, str]]:
    """Per compose service: (number of outputs, SHA-256 of their keys and bytes)."""
    feed = scenario_feed(load_scenario(scenario))
    out: dict[str, tuple[int, str]] = {}
    for name, spec in load_compose(compose_file).services.items():
        cmd = list(spec.command or [])
        if len(cmd) < 3 or cmd[1] != "run" or cmd[2] == "recorder":
            continue
        outputs = service_outputs(name, feed, compose_file)
        h = hashlib.sha256()
        for key, msg in outputs:
            h.update(key.encode())
            h.update(codec.encode(msg))
        out[name] = (len(outputs), h.hexdigest())
    return out


def main(argv: list[str]) -> int:
    for name, (n, digest) in digests(Path(argv[0] if argv else "scenarios/demo.yaml")).items():
        print(f"{name} {n} {digest}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
