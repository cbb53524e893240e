"""What a recording says about itself: the scenario a start marker names, its YAML and maps as attachments, and
the metadata records (recorder, run, services) that let a reader interpret the file without the repository.

**Names from the network open nothing outside the scenario directories.** A start marker carries a scenario
*name*, chosen by whoever published it. :func:`find_scenario` accepts only a plain name (letters, digits, ``_``,
``-``, ``.``; no path separator, not starting with ``.``) and looks for ``<dir>/<name>.yaml|.yml`` directly inside
each configured scenario directory, or a file there whose ``name:`` is that name; a candidate whose real path
(symlinks resolved) leaves its directory is ignored. A map the scenario names (``*_file`` parameters of its
simulators) is attached only if its real path is inside the scenario directory and it is small.
"""

from __future__ import annotations

import json
import logging
import os
import platform
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

import yaml

from schemas import ScenarioMarker
from shared import yaml_numbers

log = logging.getLogger("fixstream.recorder")

_PLAIN_NAME = re.compile(r"^[A-Za-z0-9_\-][A-Za-z0-9_.\-]{0,127}$")
SUFFIXES = (".yaml", ".yml")
#: scenario files read when looking a name up by its ``name:`` field, at most (and bytes each)
MAX_SCANNED_FILES = 2000
MAX_SCENARIO_BYTES = 1 << 20


def fixstream_version() -> str:
    try:
        return importlib_metadata.version("fixstream")
    except importlib_metadata.PackageNotFoundError:
        return "unknown"


def _inside(path: Path, directory: Path) -> bool:
    """Whether ``path``'s real location is a regular file inside ``directory``'s real location."""
    try:
        real, root = path.resolve(strict=True), directory.resolve(strict=True)
    except OSError:
        return False
    return real.is_file() and root in real.parents


def find_scenario(name: str, directories: Sequence[Path]) -> Path | None:
    """The scenario file a marker's ``name`` means, only inside ``directories`` (module doc); None if none."""
    if not _PLAIN_NAME.match(name) or ".." in name:
        return None
    for d in directories:
        for suffix in SUFFIXES:
            candidate = d / f"{name}{suffix}"
            if _inside(candidate, d):
                return candidate
    for d in directories:
        for candidate in _scenario_files(d):
            try:
                if candidate.stat().st_size > MAX_SCENARIO_BYTES:
                    continue
                data = yaml_numbers.load(candidate.read_text())
            except (OSError, yaml.YAMLError, UnicodeDecodeError):
                continue
            if isinstance(data, dict) and data.get("name") == name:
                return candidate
    return None


def _scenario_files(d: Path) -> Iterator[Path]:
    try:
        entries = sorted(d.iterdir())[:MAX_SCANNED_FILES]
    except OSError:
        return
    for p in entries:
        if p.suffix in SUFFIXES and _inside(p, d):
            yield p


def _map_files(params: Any) -> Iterator[str]:
    """String values of ``*_file`` keys anywhere in a simulator's parameters."""
    if isinstance(params, dict):
        for k, v in params.items():
            if isinstance(k, str) and k.endswith("_file") and isinstance(v, str):
                yield v
            else:
                yield from _map_files(v)
    elif isinstance(params, list):
        for v in params:
            yield from _map_files(v)


@dataclass
class RunContext:
    """One scenario run as the recorder saw its start marker: metadata and attachments for the file."""

    scenario: str
    seed: int
    run_index: int
    player: str
    stamp_ns: int
    scenario_path: Path | None = None
    origin: dict[str, float] | None = None
    frame_id: str = ""
    attachments: list[tuple[str, str, bytes]] = field(default_factory=list)  # (name, media type, data)
    #: the loaded scenario (services.player.scenario.Scenario), for the Foxglove converter
    loaded: Any = None

    def metadata(self) -> dict[str, str]:
        """The ``fixstream.run`` metadata record."""
        return {
            "scenario": self.scenario,
            "seed": str(self.seed),
            "run_index": str(self.run_index),
            "player": self.player,
            "start_stamp_ns": str(self.stamp_ns),
            "scenario_file": self.scenario_path.name if self.scenario_path is not None else "",
            "frame_id": self.frame_id,
            "origin": json.dumps(self.origin) if self.origin is not None else "",
            "attachments": ",".join(name for name, _, _ in self.attachments),
        }


def run_context(
    marker: ScenarioMarker, run_index: int, directories: Sequence[Path], max_attachment_bytes: int
) -> RunContext:
    """The run a start marker opens: its scenario found only inside ``directories``, read and attached."""
    ctx = RunContext(marker.scenario, marker.seed, run_index, marker.header.source, marker.header.stamp_ns)
    path = find_scenario(marker.scenario, directories)
    if path is None:
        log.warning("scenario %r not found in %s: no scenario attachment", marker.scenario, list(map(str, directories)))
        return ctx
    from services.player.scenario import ScenarioError, load_scenario

    try:
        raw = path.read_bytes()
        scenario = load_scenario(path)
    except (OSError, ScenarioError) as exc:
        log.warning("scenario %s not readable: %s", path, exc)
        return ctx
    ctx.scenario_path, ctx.loaded, ctx.frame_id = path, scenario, scenario.frame_id
    if scenario.origin is not None:
        ctx.origin = scenario.origin.model_dump()
    if len(raw) <= max_attachment_bytes:
        ctx.attachments.append((f"scenario/{path.name}", "application/yaml", raw))
    root = next((d for d in directories if _inside(path, d)), path.parent)
    for sim in scenario.simulators:
        for ref in sorted(set(_map_files(sim.params))):
            candidates = [Path(ref), root / ref, root.parent / ref]
            found = next((c for c in candidates if _inside(c, root)), None)
            if found is None:
                continue
            size = found.stat().st_size
            if size <= max_attachment_bytes:
                rel = found.resolve().relative_to(root.resolve())
                ctx.attachments.append((f"scenario/{rel.as_posix()}", "application/octet-stream", found.read_bytes()))
    return ctx


def recorder_metadata(source: str, settings_json: dict[str, Any]) -> dict[str, str]:
    """The ``fixstream.recorder`` metadata record: who wrote the file, how, and what its time fields mean."""
    return {
        "fixstream_version": fixstream_version(),
        "recorder": source,
        "host": platform.node(),
        "pid": str(os.getpid()),
        "time_fields": "log_time = publish_time = header.stamp_ns (the data clock); rejected payloads: their "
        "header's stamp if readable, else the last valid stamp (docs/recorder.md)",
        "rejected_topics": "fixstream/rejected/<original key>: payloads that failed decoding or validation, "
        "byte for byte (base64) with their Zenoh encoding and the reason",
        "config": json.dumps(settings_json, sort_keys=True, default=str),
    }


def services_metadata(
    statuses: Sequence[dict[str, Any]], alive: Sequence[str] = (), max_value_bytes: int = 65_536
) -> dict[str, str]:
    """The ``fixstream.services`` metadata record: ``<service>/<instance>`` -> its configuration (JSON), from the
    status replies of every service that answered; and ``answered`` -> how many answered of how many liveliness
    tokens were alive, and which of those did not answer (``{"answered": n, "alive": m, "missing": [...]}``)."""
    out: dict[str, str] = {}
    for st in statuses:
        who = f"{st.get('service', '?')}/{st.get('instance', '?')}"
        doc = {"config": st.get("config", {}), "version": st.get("version", "")}
        text = json.dumps(doc, sort_keys=True, default=str)
        out[who] = text if len(text) <= max_value_bytes else json.dumps({"truncated": len(text)})
    missing = sorted(set(alive) - out.keys())
    out[ANSWERED_KEY] = json.dumps({"answered": len(out), "alive": len(alive), "missing": missing})
    return out


#: the entry of ``fixstream.services`` that says how many services answered of how many were alive
ANSWERED_KEY = "answered"
