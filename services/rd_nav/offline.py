"""In-process closed loop: simulation -> RD-nav cores (one per moving AUV) [-> coordinator -> simulation].

The same cores the services run, fed with the simulation's messages in stamp order; coordinator outputs
(``BeaconAssignment``, ``DepartureGrant``) are fed back into the simulation and to every core, as the
player will do over Zenoh. Used by the acceptance tests and the benchmark; the ``fixstream mc`` plugin
can wrap :func:`run` and :mod:`.metrics`.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from schemas import AcousticArrival, BeaconTable, Header, Message
from schemas.acoustic import Beacon
from schemas.rd_nav import BeaconAssignment, DepartureGrant, RdNavFix, TdoaCycle, VehicleStatus
from shared.errors import InputRejected

from .config import RdNavConfig
from .core import RdNavCore
from .metrics import run_metrics
from .simulation import ScenarioConfig, Simulation, ref_assignment

#: cycles not scored at the start of a run: the digest scores 1437 of the 1440 cycles of a 4 h run (§5.4)
SKIP_FIRST_CYCLES = 3


class Coordinator(Protocol):
    def step(self, msg: Message) -> list[Message]: ...


@dataclass
class AuvLog:
    """What one moving AUV's core produced."""

    pf: list[tuple[float, ...]] = field(default_factory=list)  # metrics.COLUMNS
    ekf: list[tuple[float, ...]] = field(default_factory=list)
    pf_fixes: list[RdNavFix] = field(default_factory=list)
    propagated: list[tuple[float, float, float, float, str]] = field(default_factory=list)  # t, |e|, sqrt trQ
    cycles: list[TdoaCycle] = field(default_factory=list)
    rejected_inputs: Counter[str] = field(default_factory=Counter)
    cycle_status: Counter[str] = field(default_factory=Counter)  # of the PF cycle fixes


@dataclass
class RunLog:
    sim: Simulation
    cores: dict[str, RdNavCore]
    auv: dict[str, AuvLog]
    coordinator_out: list[Message] = field(default_factory=list)
    coordinator_rejects: Counter[str] = field(default_factory=Counter)

    def metrics(self, auv_id: str, skip_first_cycles: int = SKIP_FIRST_CYCLES) -> dict[str, Any]:
        """Metrics of one AUV's run; the first cycles (start-up from the R0 disc) are not scored."""
        log = self.auv[auv_id]
        core = self.cores[auv_id]
        cyc = Counter({k.removeprefix("cycle_"): v for k, v in core.counts.items() if k.startswith("cycle_")})
        k = skip_first_cycles
        return run_metrics(log.pf[k:], log.ekf[k:], core.reinit_count, cyc, log.rejected_inputs)


def node_table_message(cfg: ScenarioConfig) -> BeaconTable:
    """The surveyed node table as a ``BeaconTable`` (east/north/depth)."""
    return BeaconTable(
        header=Header(stamp_ns=cfg.start_stamp_ns, frame_id="base_ned"),
        beacons=[Beacon(beacon_id=k, x_east_m=v[1], y_north_m=v[0], depth_m=v[2]) for k, v in cfg.nodes.items()],
    )


def run(
    scenario: ScenarioConfig,
    seed: int,
    core: RdNavConfig | None = None,
    *,
    coordinator: Coordinator | None = None,
    assignment: BeaconAssignment | None = None,
    chunk_s: float = 1.0,
    keep_messages: bool = False,
) -> RunLog:
    """One closed-loop run. Without a coordinator the REF assignment (or ``assignment``) is fed at t = 0."""
    ss = np.random.SeedSequence(seed)
    sim_seed, core_seed = ss.spawn(2)
    sim = Simulation(scenario, sim_seed)
    base = core or RdNavConfig()
    table = node_table_message(scenario)
    cores: dict[str, RdNavCore] = {}
    logs: dict[str, AuvLog] = {}
    core_seeds = core_seed.generate_state(len(scenario.vehicles))
    for i, spec in enumerate(scenario.vehicles):
        cfg = base.model_copy(update={"auv_id": spec.auv_id, "seed": int(core_seeds[i])})
        c = RdNavCore(cfg)
        c.step(table)
        cores[spec.auv_id] = c
        logs[spec.auv_id] = AuvLog()
    out = RunLog(sim=sim, cores=cores, auv=logs)
    if coordinator is not None:
        coordinator.step(table)
    else:
        a = assignment or ref_assignment(scenario)
        sim.feed(a)
        for c in cores.values():
            c.step(a)

    def deliver(msgs: list[Message]) -> None:
        for m in msgs:
            out.coordinator_out.append(m)
            if isinstance(m, BeaconAssignment | DepartureGrant):
                sim.feed(m)
            if isinstance(m, BeaconAssignment):
                for c in cores.values():
                    c.step(m)

    def consume(auv_id: str, produced: list[Message]) -> None:
        log = logs[auv_id]
        for m in produced:
            if isinstance(m, RdNavFix):
                t = sim.time_of(m.header.stamp_ns)
                tx, ty = sim.truth_xy(auv_id, t)
                if m.kind == "CYCLE":
                    (x, y), q = m.estimate.mean, m.estimate.covariance
                    row = (t, x, y, q[0][0], q[0][1], q[1][1], tx, ty)
                    if m.estimator == "PF":
                        log.pf.append(row)
                        log.cycle_status[m.cycle_status] += 1
                        if keep_messages:
                            log.pf_fixes.append(m)
                    else:
                        log.ekf.append(row)
                else:
                    (x, y), q = m.estimate.mean, m.estimate.covariance
                    err = float(np.hypot(x - tx, y - ty))
                    tr = float(np.sqrt(q[0][0] + q[1][1]))
                    log.propagated.append((t, err, tr, float(m.cycles_since_update), m.status))
            elif isinstance(m, TdoaCycle) and keep_messages:
                log.cycles.append(m)

    t = 0.0
    end = scenario.duration_s
    while t < end:
        t = min(t + chunk_s, end)
        for em in sim.advance(t):
            msg = em.msg
            if em.platform == "base":
                if coordinator is not None and isinstance(msg, AcousticArrival):
                    try:
                        deliver(coordinator.step(msg))
                    except InputRejected as exc:
                        out.coordinator_rejects[exc.reason] += 1
                continue
            if isinstance(msg, VehicleStatus):
                if coordinator is not None:
                    try:
                        deliver(coordinator.step(msg))
                    except InputRejected as exc:
                        out.coordinator_rejects[exc.reason] += 1
                own = cores.get(msg.auv_id)
                if own is not None:
                    consume(msg.auv_id, own.step(msg))
                continue
            if em.kind == "truth":
                continue
            target = cores.get(em.platform)
            if target is None:
                continue
            try:
                consume(em.platform, target.step(msg))
            except InputRejected as exc:
                logs[em.platform].rejected_inputs[exc.reason] += 1
    return out


def monte_carlo(
    scenario: ScenarioConfig,
    runs: int,
    seed0: int,
    core: RdNavConfig | None = None,
    auv_id: str = "auv4",
) -> tuple[dict[str, Any], list[RunLog]]:
    """``runs`` independent runs (seeds seed0 .. seed0 + runs - 1) and their :func:`metrics.aggregate`."""
    from .metrics import aggregate

    logs = [run(scenario, seed0 + i, core) for i in range(runs)]
    return aggregate([log.metrics(auv_id) for log in logs]), logs
