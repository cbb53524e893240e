"""A scenario file that validates must also build: one line for what only building finds, never a traceback or an
out-of-memory kill.

Found by a new user's audit: ``duration_s: 1.0e+6`` with a DVL at 1,000 Hz passed ``scenarios validate``, then
``scenarios show`` grew to 24 GB and the kernel killed it; two simulators flying one platform passed too, then
``show`` and ``play`` ended in a ``SimulationError`` traceback.
"""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml
from conftest import REPO, fixstream_cmd

from services.player.scenario import load_scenario
from services.player.simulators.base import MAX_SCENARIO_SAMPLES
from services.player.timeline import SimulationError, build


def _auv_only(**changes: Any) -> dict[str, Any]:
    """The demo's first simulator (auv1, a nav_platform with five sensors), alone, with ``changes``."""
    doc = yaml.safe_load((REPO / "scenarios" / "demo.yaml").read_text())
    doc["simulators"] = doc["simulators"][:1]
    doc["estimators"] = []
    doc["wait_for"] = []
    doc.update(changes)
    return dict(doc)


def _write(tmp_path: Path, doc: dict[str, Any]) -> Path:
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(fixstream_cmd(*args), cwd=REPO, capture_output=True, text=True, timeout=120)


def _samples(doc: dict[str, Any]) -> int:
    """The periodic sensor samples the file asks for, computed from its rates: floor(T f) + 1 per sensor."""
    sim = doc["simulators"][0]["params"]
    return sum(int(doc["duration_s"] * s["rate_hz"]) + 1 for s in sim["sensors"])


@pytest.mark.parametrize("duration_s", [60.0, 1.0e5, 1.0e6])
def test_a_run_is_refused_before_it_is_built_exactly_when_it_exceeds_the_budget(
    tmp_path: Path, duration_s: float
) -> None:
    doc = _auv_only(duration_s=duration_s)
    doc["simulators"][0]["params"]["sensors"][0]["rate_hz"] = 1000.0  # the DVL
    scenario = load_scenario(_write(tmp_path, doc))
    if _samples(doc) <= MAX_SCENARIO_SAMPLES:
        assert build(scenario, 0).context.samples_reserved == _samples(doc)
    else:
        with pytest.raises(SimulationError, match="more than the"):
            build(scenario, 0)


def test_validate_show_and_play_say_it_in_one_line(tmp_path: Path, router: str) -> None:
    big = _auv_only(duration_s=1.0e6)
    big["simulators"][0]["params"]["sensors"][0]["rate_hz"] = 1000.0
    twice = _auv_only()
    twice["simulators"].append({**twice["simulators"][0], "id": "auv1b"})  # the same platform, flown again
    for name, doc, why in [("big", big, "more than the"), ("twice", twice, "flown by two simulators")]:
        (tmp_path / name).mkdir()
        path = _write(tmp_path / name, doc)
        validate = _cli("scenarios", "validate", str(path))
        assert validate.returncode == 1 and why in validate.stdout, validate.stdout + validate.stderr
        for args in (("scenarios", "show", str(path)), ("play", str(path), "--no-wait", "--connect", router)):
            done = _cli(*args)
            assert done.returncode == 2, (args, done.stdout, done.stderr)
            assert why in done.stderr and "Traceback" not in done.stderr, done.stderr


def test_the_list_keeps_its_columns_for_long_file_names(tmp_path: Path) -> None:
    """A new user's audit: names longer than 24 characters pushed their row's columns out of line."""
    for name in ("short.yaml", "a_rather_long_scenario_file_name_indeed.yaml"):
        (tmp_path / name).write_text(yaml.safe_dump(_auv_only(name=Path(name).stem)))
    (tmp_path / "broken.yaml").write_text("name: [\n")
    out = _cli("scenarios", "--dir", str(tmp_path)).stdout.splitlines()
    valid = [line for line in out if "INVALID" not in line]
    assert len(valid) == 2 and len(out) == 3
    assert len({line.index(" s ") for line in valid}) == 1  # the duration column ends at one place
    assert len({line.index(Path(line.split()[0]).stem, len(line.split()[0])) for line in valid}) == 1
