"""A recording split the way the metrics and the plots need it.

* **The scenario.** The player's start marker (``fixstream/scenario/<name>``) names the scenario and carries
  the seed (without a marker: the recording's ``fixstream.run`` metadata, :mod:`.carried`). The scenario is
  ``--scenario`` if given; else the one of that name attached to the recording (so a recording copied anywhere
  reports the same); else the name looked up in the scenarios directory (``--scenarios-dir``, default
  ``$FIXSTREAM_SCENARIOS_DIR`` or ``scenarios/``) as ``fixstream play`` looks names up. Without one the report
  still draws every estimator, but has no Monte-Carlo metrics.
* **Events**: what the player (or a sensor) published — every message from a ``player/*`` source and every
  message on ``fixstream/sensor/**`` and ``fixstream/truth/**``, markers excepted — as
  :class:`~services.player.simulators.Event` s in recorded order (the order ``fixstream mc`` feeds its plugins,
  key by key).
* **Outputs**: per publisher (``header.source`` = ``<service>/<instance>``), everything it published except its
  diagnostics, as Events in recorded order (per key, publication order).
* **Diagnostics**: per publisher, the last running counts of its ``Diagnostic`` messages.
* **Truth**: per platform, the ``Truth`` positions in scenario ENU (:mod:`shared.foxglove.frames`), for
  interpolation at any stamp.
"""

from __future__ import annotations

import os
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from schemas import Diagnostic, ScenarioMarker, Truth
from services.player.scenario import (
    Scenario,
    ScenarioError,
    default_dir,
    load_scenario,
    parse_scenario,
    resolve,
    scenario_files,
)
from services.player.simulators import Event
from shared import keys, yaml_numbers
from shared.foxglove.frames import F64, FrameContext

from .carried import Carried
from .reading import Recording, ReportError

_SENSOR_OR_TRUTH = (f"{keys.ROOT}/sensor/", f"{keys.ROOT}/truth/")


@dataclass
class TruthSeries:
    """One platform's truth: stamps (s), ENU positions (n, 3), and headings/pitch/roll where given (n, 3)."""

    platform: str
    t_s: F64
    pos: F64
    attitude_rad: F64 | None = None
    extra: list[dict[str, float]] = field(default_factory=list)
    #: ENU velocities (n, 3), NaN rows where a sample has none
    vel: F64 | None = None

    def at(self, t_s: F64) -> F64:
        """Positions (m, 3) at the stamps: linear between samples, NaN outside the sampled span."""
        q = np.asarray(t_s, dtype=np.float64)
        out = np.full((q.size, 3), np.nan)
        if self.t_s.size == 0:
            return out
        if self.t_s.size == 1:
            hit = np.isclose(q, self.t_s[0], rtol=0.0, atol=1e-6)
            out[hit] = self.pos[0]
            return out
        inside = (q >= self.t_s[0] - 1e-9) & (q <= self.t_s[-1] + 1e-9)
        for c in range(3):
            out[inside, c] = np.interp(q[inside], self.t_s, self.pos[:, c])
        return out

    def vel_at(self, t: float) -> F64 | None:
        """Velocity (3,) at ``t``: linear between samples; None outside the span or where none is given."""
        if self.vel is None or self.t_s.size == 0 or not self.t_s[0] - 1e-9 <= t <= self.t_s[-1] + 1e-9:
            return None
        v = np.array([np.interp(t, self.t_s, self.vel[:, c]) for c in range(3)])
        return v if np.all(np.isfinite(v)) else None

    def vel_at_many(self, t_s: F64) -> F64:
        """Velocities (m, 3) at the stamps: linear between samples, NaN outside the span or where none is given."""
        q = np.asarray(t_s, dtype=np.float64)
        out = np.full((q.size, 3), np.nan)
        if self.vel is None or self.t_s.size < 2:
            return out
        inside = (q >= self.t_s[0] - 1e-9) & (q <= self.t_s[-1] + 1e-9)
        for c in range(3):
            out[inside, c] = np.interp(q[inside], self.t_s, self.vel[:, c])
        return out

    def index_at(self, t: float) -> int | None:
        """Index of the sample at exactly ``t`` (within 1 µs), else None."""
        i = int(np.searchsorted(self.t_s, t - 1e-6))
        if i < self.t_s.size and abs(self.t_s[i] - t) <= 1e-6:
            return i
        return None


@dataclass
class RunData:
    """Everything the metrics and sections read (see the module doc)."""

    recording: Recording
    scenario: Scenario | None
    #: where the scenario came from: a file path or ``<attachment> (attached to the recording)``
    scenario_origin: str | None
    scenario_name: str | None
    seed: int | None
    #: the recorder's count of this scenario's runs, 1 for the first (``run_index`` of its ``fixstream.run``
    #: metadata; not the Monte-Carlo run of ``fixstream play --run``)
    run_index: int | None
    ctx: FrameContext
    events: list[Event]
    outputs: dict[str, list[Event]]
    diagnostics: dict[str, dict[str, int]]
    truth: dict[str, TruthSeries]
    notes: list[str] = field(default_factory=list)
    _by_key: dict[str, list[Event]] | None = field(default=None, init=False, repr=False)

    def events_on(self, key: str) -> list[Event]:
        """The events on one key, in recorded order."""
        if self._by_key is None:
            idx: dict[str, list[Event]] = defaultdict(list)
            for ev in self.events:
                idx[ev.key].append(ev)
            self._by_key = dict(idx)
        return self._by_key.get(key, [])

    def sources(self, service: str) -> list[str]:
        """Publishers ``<service>/<instance>`` with outputs in the recording, sorted."""
        return sorted(s for s in self.outputs if s.split("/", 1)[0] == service)

    @property
    def t_end_s(self) -> float:
        stamps = [ev.stamp_ns for ev in self.events[-1:]] + [o[-1].stamp_ns for o in self.outputs.values() if o]
        return max(stamps, default=0) / 1e9


def _dir(d: str | os.PathLike[str] | None) -> Path | None:
    return None if d is None else Path(d)


@dataclass
class ScenarioChoice:
    """The scenario the report uses and where it came from."""

    scenario: Scenario | None
    #: where it came from: a file path, or ``<attachment> (attached to the recording)``; None: no scenario
    origin: str | None
    name: str | None
    seed: int | None
    run_index: int | None
    notes: list[str] = field(default_factory=list)


def find_scenario(
    rec: Recording,
    scenario: str | os.PathLike[str] | None,
    scenarios_dir: str | os.PathLike[str] | None,
    carried: Carried | None = None,
) -> ScenarioChoice:
    """The scenario of the recording: ``--scenario`` if given; else the one the start marker (or the run
    metadata) names — first as attached to the recording, so a copied file reports the same anywhere, then looked
    up by name in the scenarios directory as ``fixstream play`` looks names up (a bare name only: a marker
    naming a path opens nothing)."""
    carried = carried or Carried()
    # an attachment that could not be read (not YAML, not readable) is said, not only missed
    notes: list[str] = [f"what the recording carries could not all be read: {p}" for p in carried.problems]
    starts = [m for _, m in rec.markers if m.event == "start"]
    name = starts[0].scenario if starts else carried.run_scenario
    seed = starts[0].seed if starts else carried.run_seed
    run_index = carried.run_index
    if len(starts) > 1:
        notes.append(f"the recording holds {len(starts)} scenario runs; their data are reported together")
    if scenario is not None:
        try:
            path = Path(scenario)
            path = path if path.is_file() else resolve(str(scenario), _dir(scenarios_dir))
            sc = load_scenario(path)
        except ScenarioError as exc:
            raise ReportError(f"--scenario: {exc}") from None
        if name is not None and sc.name != name:
            notes.append(f"the recording's start marker names scenario {name!r}; reported with {sc.name!r}")
        return ScenarioChoice(sc, str(path), sc.name, seed, run_index, notes)
    attached = carried.scenario_for(name)
    if attached is not None:
        try:
            sc = parse_scenario(attached.document, attached.name)
            return ScenarioChoice(sc, f"{attached.name} (attached to the recording)", sc.name, seed, run_index, notes)
        except ScenarioError as exc:
            notes.append(f"the scenario attached to the recording ({attached.name}) is not valid here: {exc}")
    if name is None:
        notes.append("no scenario start marker in the recording: no scenario, no Monte-Carlo metrics")
        return ScenarioChoice(None, None, None, None, run_index, notes)
    try:
        path = _by_name(name, _dir(scenarios_dir) or default_dir())
        return ScenarioChoice(load_scenario(path), str(path), name, seed, run_index, notes)
    except ScenarioError as exc:
        attached_how = "no readable attachment of it (above)" if carried.problems else "not attached to the recording"
        notes.append(
            f"scenario {name!r} of the start marker: {attached_how}, not found by name ({exc}); give it with --scenario"
        )
        return ScenarioChoice(None, None, name, seed, run_index, notes)


def _by_name(name: str, directory: Path) -> Path:
    """The file of the scenario called ``name`` in ``directory``: ``<name>.yaml|.yml`` or a file there whose
    ``name:`` it is. A name from the recording is a name, never a path (a marker naming ``../x`` opens nothing)."""
    if not name or any(c in name for c in "/\\\0") or name.startswith(".") or len(name) > 256:
        raise ScenarioError(f"{name!r} is not a scenario name (names only, no paths)")
    for suffix in (".yaml", ".yml"):
        if (directory / f"{name}{suffix}").is_file():
            return directory / f"{name}{suffix}"
    for f in scenario_files(directory):
        try:
            doc = yaml_numbers.load(f.read_text())
        except (OSError, yaml.YAMLError, UnicodeDecodeError):
            continue
        if isinstance(doc, dict) and doc.get("name") == name:
            return f
    raise ScenarioError(f"no scenario named {name!r} in {directory}/")


def split(rec: Recording, scenario: Scenario | None) -> tuple[list[Event], dict[str, list[Event]], dict[str, Any]]:
    """(events, outputs per publisher, last diagnostic counts per publisher) of the recording."""
    events: list[Event] = []
    outputs: dict[str, list[Event]] = defaultdict(list)
    diags: dict[str, dict[str, int]] = {}
    for ev in rec.items:
        msg = ev.msg
        if isinstance(msg, ScenarioMarker):
            continue
        source = msg.header.source
        if isinstance(msg, Diagnostic):
            diags[source or f"{msg.service}/{msg.instance}"] = dict(msg.counts)
        elif source.startswith("player/") or ev.key.startswith(_SENSOR_OR_TRUTH):
            events.append(ev)
        else:
            outputs[source].append(ev)
    return events, dict(outputs), diags


def cut_short(rec: Recording, scenario: Scenario | None) -> str | None:
    """A note when the recording holds a scenario's start marker but not its end: the run was interrupted (Ctrl-C,
    a failed service) and every figure covers only what was recorded; None for a run that ended."""
    markers = [m for _, m in rec.markers]
    if not markers or markers[-1].event != "start":  # no scenario, or its (last) run ended
        return None
    last = max((ev.msg.header.stamp_ns for ev in rec.items), default=0) / 1e9
    of = f" of the scenario's {scenario.duration_s:g} s" if scenario is not None else ""
    return (
        f"the run was cut short: the recording has the scenario's start marker but not its end (interrupted, or a"
        f" process failed); its data end at {last:.1f} s{of}, and every figure and verdict covers only that"
    )


def truth_series(items: list[Event], ctx: FrameContext) -> dict[str, TruthSeries]:
    """Per platform, the Truth positions (and velocities) in scenario ENU, in stamp order."""
    rows: dict[tuple[str, str], list[Truth]] = defaultdict(list)
    for it in items:
        msg = it.msg
        if isinstance(msg, Truth):
            rows[(msg.platform, msg.header.frame_id)].append(msg)
    out: dict[str, TruthSeries] = {}
    for (platform, frame), msgs in rows.items():
        if platform in out:  # one platform in two frames: keep the first (a broken recording)
            continue
        msgs.sort(key=lambda m: m.header.stamp_ns)
        pos = ctx.to_enu_array(np.array([m.position_m for m in msgs], dtype=np.float64).reshape(-1, 3), frame)
        vel = np.array(
            [m.velocity_mps if m.velocity_mps is not None else (np.nan, np.nan, np.nan) for m in msgs],
            dtype=np.float64,
        ).reshape(-1, 3)
        vel = ctx.to_enu_array(vel, frame, axes=ctx.axes(frame)[0])
        att = None
        if all(m.attitude_rad is not None for m in msgs):
            att = np.array([m.attitude_rad for m in msgs], dtype=np.float64)
        out[platform] = TruthSeries(
            platform,
            np.array([m.header.stamp_ns for m in msgs], dtype=np.float64) / 1e9,
            pos,
            att,
            [m.extra for m in msgs],
            vel,
        )
    return out


def run_data(
    rec: Recording,
    scenario: str | os.PathLike[str] | None = None,
    scenarios_dir: str | os.PathLike[str] | None = None,
    carried: Carried | None = None,
) -> RunData:
    """Split a read recording (see the module doc)."""
    choice = find_scenario(rec, scenario, scenarios_dir, carried)
    sc = choice.scenario
    ctx = FrameContext.from_scenario(sc)
    events, outputs, diags = split(rec, sc)
    notes = [*rec.notes, *choice.notes]
    cut = cut_short(rec, sc)
    if cut:
        notes.append(cut)
    return RunData(
        recording=rec,
        scenario=sc,
        scenario_origin=choice.origin,
        scenario_name=choice.name,
        seed=choice.seed,
        run_index=choice.run_index,
        ctx=ctx,
        events=events,
        outputs=outputs,
        diagnostics=diags,
        truth=truth_series(events, ctx),
        notes=notes,
    )


__all__ = [
    "RunData",
    "ScenarioChoice",
    "TruthSeries",
    "cut_short",
    "find_scenario",
    "run_data",
    "split",
    "truth_series",
]
