"""What a recording carries about itself: the scenario it played (an attachment) and its run (metadata).

So that ``fixstream report FILE`` works from any directory with only the file, the report reads, before looking a
scenario up by name, what the recorder wrote into the file (docs/recorder.md, issue 17):

* **attachments**: the scenario YAML as played, named ``scenario/<file>.yaml`` (or ``scenario.yaml``), and the
  maps it names (not needed by the report: the figures and metrics use the published outputs and the truth);
* **metadata**: the record ``fixstream.run`` (or ``fixstream``) with ``scenario``, ``seed`` and ``run_index``
  (``run``: the recorder's count of this scenario's runs, 1 for the first) — the run's facts when the start marker
  is missing.

Read with the ``mcap`` package's reader: a finalised file through its summary's indexes (a few seeks), an
unfinalised one by a linear scan. A file whose attachments or metadata cannot be read contributes nothing here
(its messages are read — or refused with a clear error — by :mod:`.reading`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

import yaml

from shared import yaml_numbers

#: the metadata records that describe the run (the recorder's name first)
RUN_METADATA = ("fixstream.run", "fixstream")
#: the largest scenario attachment parsed (the recorder attaches at most 4 MB)
MAX_SCENARIO_BYTES = 4 << 20
_YAML = (".yaml", ".yml")


@dataclass
class CarriedScenario:
    """A scenario document attached to the recording."""

    #: the attachment's name (``scenario/demo.yaml``)
    name: str
    #: the file it was attached to
    file: Path
    #: the parsed YAML document (validated later, by :func:`services.player.scenario.parse_scenario`)
    document: Any

    @property
    def scenario_name(self) -> str | None:
        doc = self.document
        return str(doc["name"]) if isinstance(doc, dict) and "name" in doc else None


@dataclass
class Carried:
    """The scenarios attached to a recording and its run metadata (empty when the files carry none)."""

    scenarios: list[CarriedScenario] = field(default_factory=list)
    #: the run metadata record (``fixstream.run`` or ``fixstream``) of the first file that has one
    run: dict[str, str] = field(default_factory=dict)
    #: names of every metadata record seen (for the page's run facts)
    metadata_names: list[str] = field(default_factory=list)
    #: why a file's attachments or metadata could not be read
    problems: list[str] = field(default_factory=list)

    def scenario_for(self, name: str | None) -> CarriedScenario | None:
        """The attached scenario called ``name`` (its ``name:`` field); with no name, the only one attached."""
        if name is not None:
            return next((s for s in self.scenarios if s.scenario_name == name), None)
        names = {s.scenario_name for s in self.scenarios}
        return self.scenarios[0] if len(names) == 1 else None

    @property
    def run_scenario(self) -> str | None:
        return self.run.get("scenario") or None

    @property
    def run_seed(self) -> int | None:
        return _int(self.run.get("seed"))

    @property
    def run_index(self) -> int | None:
        return _int(self.run.get("run_index", self.run.get("run")))


def _int(value: str | None) -> int | None:
    try:
        return int(value) if value not in (None, "") else None
    except ValueError:
        return None


def is_scenario_attachment(name: str) -> bool:
    """``scenario.yaml``, or a ``.yaml``/``.yml`` directly under ``scenario/`` (the maps the recorder attaches sit
    there too, under their own names and suffixes, or deeper)."""
    p = PurePosixPath(name)
    if p.suffix not in _YAML:
        return False
    if p.stem == "scenario" and len(p.parts) == 1:
        return True
    return len(p.parts) == 2 and p.parts[0] == "scenario"


def read_carried(files: Sequence[Path]) -> Carried:
    """The attached scenarios (each name once, first file first) and the run metadata of the files."""
    from mcap.reader import make_reader

    out = Carried()
    seen: set[tuple[str, int]] = set()
    for path in files:
        try:
            with path.open("rb") as f:
                reader = make_reader(f)
                try:
                    for meta in reader.iter_metadata():
                        out.metadata_names.append(meta.name)
                        if meta.name in RUN_METADATA and not out.run:
                            out.run = {str(k): str(v) for k, v in meta.metadata.items()}
                finally:  # a truncated file: what came before the cut still counts
                    for att in reader.iter_attachments():
                        if not is_scenario_attachment(att.name) or len(att.data) > MAX_SCENARIO_BYTES:
                            continue
                        if (att.name, len(att.data)) in seen:  # the recorder repeats them in every rotated file
                            continue
                        seen.add((att.name, len(att.data)))
                        try:
                            doc = yaml_numbers.load(bytes(att.data).decode("utf-8"))
                        except (yaml.YAMLError, UnicodeDecodeError) as exc:
                            out.problems.append(f"{path.name}: attachment {att.name}: not YAML: {exc}")
                            continue
                        out.scenarios.append(CarriedScenario(att.name, path, doc))
        except Exception as exc:  # a truncated or odd file: its messages are handled by .reading
            out.problems.append(f"{path.name}: attachments and metadata not readable: {type(exc).__name__}: {exc}")
    out.metadata_names = list(dict.fromkeys(out.metadata_names))
    return out


__all__ = ["RUN_METADATA", "Carried", "CarriedScenario", "is_scenario_attachment", "read_carried"]
