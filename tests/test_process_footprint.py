"""What a service process imports: only what its service needs (issue 19 item 6, issue 18's fleet memory).

Each check runs in a fresh interpreter, because this test process has imported everything already. The plugin
registry is read by every ``fixstream`` command; if loading it imported each estimator's core, every process
would carry every estimator's dependencies (SciPy alone is ~40 MB of private memory per process, which is what
limited the N = 200 row of ``bench/bench_scaling.py``).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
HEAVY = ("scipy", "matplotlib", "rasterio", "pandas", "pyarrow", "mcap", "foxglove")


def _modules_after(code: str, env: dict[str, str] | None = None) -> set[str]:
    probe = code + "\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))\n"
    out = subprocess.run(
        [sys.executable, "-c", probe], cwd=REPO, capture_output=True, text=True, check=True, env=env, timeout=120
    )
    return set(json.loads(out.stdout.strip().splitlines()[-1]))


def test_loading_the_plugin_registry_imports_no_estimator_core() -> None:
    mods = _modules_after("from shared.plugins import plugins\nplugins()")
    cores = sorted(m for m in mods if m.startswith("services.") and m.rsplit(".", 1)[-1] in ("core", "simulator"))
    assert cores == []
    assert not {m.split(".")[0] for m in mods} & set(HEAVY)


@pytest.mark.parametrize(("name", "allowed"), [("terrain_nav", ()), ("coordinator", ()), ("recorder", ("foxglove",))])
def test_a_service_process_imports_only_its_own_dependencies(name: str, allowed: tuple[str, ...]) -> None:
    import os

    env = {**os.environ, "FIXSTREAM_TERRAIN_NAV_MAP_PATH": str(REPO / "scenarios/maps/terrain_nav_informative.npy")}
    mods = _modules_after(f"from tools.registry import load_service\nload_service({name!r})", env)
    heavy = {m.split(".")[0] for m in mods} & set(HEAVY)
    assert heavy <= set(allowed), f"{name} imports {sorted(heavy - set(allowed))}"
    # every plugin.py is read (the registry); beyond that, only the service's own package and the runtime
    others = {
        m.split(".")[1] for m in mods if m.startswith("services.") and m.count(".") >= 2 and not m.endswith(".plugin")
    }
    assert others <= {name, "player"} | ({"rd_nav"} if name == "coordinator" else set()), others
