"""The lock file is the program the tests run: every declared dependency is pinned there, with hashes."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from packaging.markers import Marker, default_environment
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

REPO = Path(__file__).resolve().parents[1]
_PIN = re.compile(r"^(?P<name>[A-Za-z0-9_.\-]+)==(?P<version>[^\s;\\]+)\s*(?:;(?P<marker>[^\\]+))?\\?$")


def _pins() -> dict[str, list[tuple[str, str | None, int]]]:
    """name -> [(version, marker, number of hashes)] from requirements.lock."""
    pins: dict[str, list[tuple[str, str | None, int]]] = {}
    current: list[tuple[str, str | None, int]] | None = None
    for line in (REPO / "requirements.lock").read_text().splitlines():
        m = _PIN.match(line.strip())
        if m and not line.startswith(" "):
            marker = m.group("marker")
            entry = (m.group("version"), marker.strip() if marker else None, 0)
            current = pins.setdefault(canonicalize_name(m.group("name")), [])
            current.append(entry)
        elif line.strip().startswith("--hash=sha256:") and current:
            version, marker, n = current[-1]
            current[-1] = (version, marker, n + 1)
    return pins


def _declared() -> list[Requirement]:
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    reqs = [*project["dependencies"], *project["optional-dependencies"]["dev"]]
    build = tomllib.loads((REPO / "pyproject.toml").read_text())["build-system"]["requires"]
    return [Requirement(r) for r in [*reqs, *build]]


def test_every_declared_dependency_is_pinned_with_hashes_and_fits_its_range() -> None:
    pins = _pins()
    env = {k: str(v) for k, v in default_environment().items()}
    for req in _declared():
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} is in pyproject.toml but not in requirements.lock: run make lock"
        usable = [(v, n) for v, marker, n in pins[name] if marker is None or Marker(marker).evaluate(env)]
        assert len(usable) == 1, f"{req.name}: expected one pin for this Python, got {usable}"
        version, hashes = usable[0]
        assert req.specifier.contains(version, prereleases=True), f"{req.name}=={version} outside {req.specifier}"
        assert hashes >= 1, f"{req.name}=={version} has no hash"


def test_every_pin_carries_hashes_and_the_install_requires_them() -> None:
    pins = _pins()
    assert len(pins) > 20
    for name, entries in pins.items():
        for version, _, hashes in entries:
            assert hashes >= 1, f"{name}=={version} has no hash"
    makefile = (REPO / "Makefile").read_text()
    assert "--require-hashes --no-deps -r $(LOCK)" in makefile
    assert "--no-deps --no-build-isolation -e ." in makefile
