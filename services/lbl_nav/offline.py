"""Run the core over simulated runs in-process and collect per-epoch traces for the metrics.

The same ``LblNavCore.step`` the service calls is fed the simulator's messages in order; rejected inputs are
counted. ``stop_when_resolved`` ends a run once one hypothesis remains (enough for resolution-time statistics).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from schemas import Message
from schemas.lbl_nav import LblEvent, LblFix
from shared.errors import InputRejected

from .config import LblNavConfig
from .core import LblNavCore
from .epochs import NS
from .simulation import ScenarioSpec, SimRun, simulate

F64 = NDArray[np.float64]


@dataclass
class RunTrace:
    """Post-launch per-epoch record of one run (index 0 = launch epoch, t relative to t_0 in s)."""

    seed: int
    launched: bool
    t_s: F64 = field(default_factory=lambda: np.zeros(0))
    n_hyp: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    valid: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    pos: F64 = field(default_factory=lambda: np.zeros((0, 2)))  # NaN while ambiguous
    var: F64 = field(default_factory=lambda: np.zeros((0, 2)))  # filter variances of x, y
    truth: F64 = field(default_factory=lambda: np.zeros((0, 2)))
    log10_ratio: F64 = field(default_factory=lambda: np.zeros(0))
    catching_up: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    hyp_pos: dict[int, F64] = field(default_factory=dict)  # per hypothesis id, NaN when not alive
    true_label: int | None = None  # hypothesis id nearest to the truth at launch
    decided: int | None = None  # u* of the decision, if any
    resolution_t_s: float | None = None  # time of decision or merge after launch
    merged: bool = False
    rejected_inputs: int = 0
    events: list[LblEvent] = field(default_factory=list)
    fixes_pre_launch: int = 0

    @property
    def wrong(self) -> bool:
        return self.decided is not None and self.true_label is not None and self.decided != self.true_label

    def unambiguous_at(self, t: float) -> bool:
        return self.resolution_t_s is not None and self.resolution_t_s <= t

    def correct_at(self, t: float) -> bool:
        return self.unambiguous_at(t) and not self.wrong


def feed(core: LblNavCore, messages: list[Message], stop_when_resolved: bool = False) -> tuple[list[Message], int]:
    """Step the core over the messages (then flush); returns outputs and the number of rejected inputs."""
    outs: list[Message] = []
    rejected = 0
    for m in messages:
        try:
            outs += core.step(m)
        except InputRejected:
            rejected += 1
        if stop_when_resolved and core.bank is not None and len(core.bank.hyps) == 1 and outs:
            break
    outs += core.flush()
    return outs, rejected


def run_core(cfg: LblNavConfig, sim: SimRun, stop_when_resolved: bool = False) -> RunTrace:
    """One run: feed the simulated messages to a fresh core and build the trace against the truth."""
    core = LblNavCore(cfg)
    outs, rejected = feed(core, sim.messages, stop_when_resolved)
    truth = {int(s): (float(x), float(y)) for s, x, y in zip(sim.stamps_ns, sim.x_m, sim.y_m, strict=True)}
    return trace_from_outputs(outs, truth, int(sim.stamps_ns[sim.i0]), sim.seed, rejected)


def trace_from_outputs(
    outs: Sequence[Message],
    truth_xy: Mapping[int, tuple[float, float]],
    t0_ns: int,
    seed: int = 0,
    rejected: int = 0,
) -> RunTrace:
    """The trace of one run from the estimator's outputs (its ``LblFix`` and ``LblEvent`` messages, in order) and
    the true horizontal position at each epoch stamp; times are relative to the simulated launch epoch ``t0_ns``
    (the epoch at which two beacons are first heard; the core's launch, if it is postponed, is later)."""
    fixes = [o for o in outs if isinstance(o, LblFix)]
    events = [o for o in outs if isinstance(o, LblEvent)]
    post = [f for f in fixes if f.launch_stamp_ns is not None and f.header.stamp_ns >= f.launch_stamp_ns]
    tr = RunTrace(seed=seed, launched=bool(post), rejected_inputs=rejected, events=events)
    tr.fixes_pre_launch = len(fixes) - len(post)
    if not post:
        return tr
    # only the first launch (a re-launch after divergence starts a new record; not expected in the scenarios)
    launch_ns = post[0].launch_stamp_ns
    assert launch_ns is not None
    post = [f for f in post if f.launch_stamp_ns == launch_ns and f.header.stamp_ns in truth_xy]
    n = len(post)
    tr.t_s = np.array([(f.header.stamp_ns - t0_ns) / NS for f in post], dtype=np.float64)
    tr.truth = np.array([truth_xy[f.header.stamp_ns] for f in post], dtype=np.float64).reshape(n, 2)
    tr.n_hyp = np.array([len(f.hypotheses) for f in post], dtype=np.int64)
    tr.valid = np.array([f.valid for f in post], dtype=bool)
    tr.pos = np.full((n, 2), np.nan)
    tr.var = np.full((n, 2), np.nan)
    tr.log10_ratio = np.array([np.nan if f.log10_ratio is None else f.log10_ratio for f in post])
    tr.catching_up = np.array([f.catching_up for f in post], dtype=bool)
    for j, f in enumerate(post):
        if f.valid and f.estimate is not None:
            tr.pos[j] = f.estimate.mean[:2]
            tr.var[j] = (f.estimate.covariance[0][0], f.estimate.covariance[1][1])
        for h in f.hypotheses:
            arr = tr.hyp_pos.setdefault(h.hypothesis_id, np.full((n, 2), np.nan))
            arr[j] = h.estimate.mean[:2]
    if n and len(post[0].hypotheses) == 2:
        d = {h.hypothesis_id: math.dist(h.estimate.mean[:2], tr.truth[0]) for h in post[0].hypotheses}
        tr.true_label = min(d, key=lambda u: d[u])
    for f in post:
        if f.resolved_stamp_ns is not None:
            tr.resolution_t_s = (f.resolved_stamp_ns - launch_ns) / NS
            tr.merged = f.hypothesis_source == "merged"
            if f.hypothesis_source == "resolved":
                tr.decided = f.accepted_hypothesis
            break
    return tr


# ---- Monte-Carlo sets of the digest's scenarios (section 4.2) --------------------------------------------------------
def scenario_config(name: str, **overrides: object) -> LblNavConfig:
    """Core configuration of a scenario (the paper's rule (6), ``preset: paper``, unless overridden): S1/S3/S4 the
    paper's simulation values (N = 360), S2 the field values
    (N = 97, no heading or current error: sigma_dK = sigma_dU = 0). ``validate_outputs`` is off for speed."""
    base: dict[str, object] = {"N_max": 360, "validate_outputs": False, "preset": "paper"}
    if name == "S2":
        base.update(N_max=97, sigma_dK_rad=0.0, sigma_dU_mps=0.0)
    base.update(overrides)
    return LblNavConfig(**base)  # type: ignore[arg-type]


def run_set(
    spec: ScenarioSpec,
    configs: Sequence[LblNavConfig],
    seeds: Sequence[int],
    stop_when_resolved: bool = False,
) -> list[list[RunTrace]]:
    """For each seed one simulated run, fed to one fresh core per configuration (paired comparisons)."""
    out: list[list[RunTrace]] = [[] for _ in configs]
    for seed in seeds:
        sim = simulate(spec, np.random.default_rng(seed), seed)
        for j, cfg in enumerate(configs):
            out[j].append(run_core(cfg, sim, stop_when_resolved))
    return out
