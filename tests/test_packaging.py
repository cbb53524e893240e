"""What a wheel of fixstream carries besides Python modules: the files the code finds beside itself at run time.

The secure router's access control (``tools.stack.pki.ROUTER_ACL``) used to be resolved as ``<repo>/config/...``,
which exists only in a checkout or an editable install; ``fixstream up --secure`` from a wheel (or in the image)
then pointed the router at a missing file. It is package data now: this test builds the wheel from a copy of the
sources (so the worktree gets no ``build/``), unpacks it, and imports ``tools.stack.pki`` from the unpacked tree
alone, in a directory that is not the repository.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

from conftest import REPO

#: what pyproject.toml's build reads
SOURCES = ("pyproject.toml", "README.md", "schemas", "shared", "services", "tools")


def _build_wheel(tmp_path: Path) -> Path:
    src = tmp_path / "src"
    src.mkdir()
    for name in SOURCES:
        path = REPO / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(path, src / name)
    out = tmp_path / "dist"
    argv = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(out), str(src)]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (wheel,) = out.glob("fixstream-*.whl")
    return wheel


def test_the_router_access_control_is_in_the_wheel_and_found_from_it(tmp_path: Path) -> None:
    wheel = _build_wheel(tmp_path)
    with zipfile.ZipFile(wheel) as zf:
        packed = zf.read("tools/stack/router-secure.json5")
        zf.extractall(tmp_path / "site")
    assert packed == (REPO / "tools" / "stack" / "router-secure.json5").read_bytes()
    probe = (
        "import json, sys; sys.path.insert(0, sys.argv[1]); from tools.stack.pki import ROUTER_ACL; "
        "print(json.dumps([str(ROUTER_ACL), ROUTER_ACL.is_file()]))"
    )
    elsewhere = tmp_path / "cwd"
    elsewhere.mkdir()
    proc = subprocess.run(
        [sys.executable, "-c", probe, str(tmp_path / "site")],
        cwd=elsewhere,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    path, exists = json.loads(proc.stdout)
    assert path == str(tmp_path / "site" / "tools" / "stack" / "router-secure.json5")
    assert exists
