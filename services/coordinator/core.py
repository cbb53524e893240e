"""Base-station coordinator core (digest 002 §2.4, §4.8, §7.3 S7): ``step(msg) -> outputs``.

Inputs: ``VehicleStatus`` (DOCKED, SERVICE_DONE, AT_BASE, DEPARTED, FAULT, HEARTBEAT), ``AcousticArrival``
heard at the base (marks beacons as alive, confirms a new epoch) and ``BeaconTable`` (node table,
east/north/depth). Outputs: ``BeaconAssignment`` (new epoch whenever the active set changes) and
``DepartureGrant``.

Rules:

* the beacons are the docked AUVs (and, if configured, those parked at the base);
* departures are granted FIFO by service-complete report time, only if at least ``min_beacons`` *other*
  beacons remain (§2.4); a candidate in the active set is first re-assigned away (new epoch) and the grant
  follows ``grant_delay_s`` later or once a packet of the new epoch is heard;
* the active set is re-selected on every registry change and every ``reselect_period_s`` (§4.8, hysteresis);
* an active beacon not heard for ``beacon_timeout_s`` is removed (alarm ``beacon_timeout``).

Time is the data clock of the inputs (``header.stamp_ns``), seconds since the first input.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from schemas import AcousticArrival, BeaconTable, Header, Message
from schemas.rd_nav import BeaconAssignment, DepartureGrant, VehicleStatus
from shared.errors import InputRejected
from shared.keys import is_chunk

from .config import CoordinatorConfig
from .registry import DOCKED_STATES, F64, VehicleRecord, route_points
from .selection import Selection, select


class CoordinatorCore:
    """Vehicle registry, the departure rule and the beacon-set selection of the base station."""

    def __init__(self, config: CoordinatorConfig | None = None) -> None:
        self.cfg = cfg = config or CoordinatorConfig()
        self.nodes: dict[str, F64] = {k: np.array(v, dtype=np.float64) for k, v in cfg.node_table_ned_m.items()}
        self.vehicles: dict[str, VehicleRecord] = {}
        self.done_queue: list[tuple[float, str]] = []
        self.assignment: BeaconAssignment | None = None
        self.selection: Selection | None = None
        self.epoch = 0
        self.pending: tuple[str, float, int] | None = None  # (auv, not before, epoch)
        self.heard_epoch = -1
        self.preliminary_over = False
        self.alarms: Counter[str] = Counter()
        self.grants: list[tuple[float, str, int]] = []
        self._t0_ns: int | None = None
        self.t = 0.0
        self._last_reselect = -math.inf
        self._active_since: dict[str, float] = {}

    # ======================================================================= public =====
    def step(self, msg: Message) -> list[Message]:
        if isinstance(msg, BeaconTable):
            for b in msg.beacons:
                if not all(math.isfinite(v) for v in (b.x_east_m, b.y_north_m, b.depth_m)):
                    raise InputRejected("non_finite", f"node {b.beacon_id} position is not finite")
            for b in msg.beacons:
                self.nodes[b.beacon_id] = np.array([b.y_north_m, b.x_east_m, b.depth_m])
            return []
        if isinstance(msg, VehicleStatus):
            pos = self._check_status(msg)  # refuse before any state change (the clock included)
            t = self._time(msg.header.stamp_ns)
            changed = self._on_status(msg, t, pos)
            return self._after(t, changed)
        if isinstance(msg, AcousticArrival):
            pk = msg.packet
            rec = self.vehicles.get(pk.sender_id)
            if rec is None:
                raise InputRejected("unknown_sender", f"{pk.sender_id} is not in the registry")
            t = self._time(msg.header.stamp_ns)
            rec.last_heard_s = t
            a = self.assignment
            if a is not None and pk.assignment_epoch == a.epoch and pk.sender_id == a.leader_id:
                self.heard_epoch = max(self.heard_epoch, pk.assignment_epoch)
            return self._after(t, False)
        raise InputRejected("unsupported_type", f"{type(msg).__name__} is not an input of the coordinator")

    def tick(self, stamp_ns: int) -> list[Message]:
        """Advance the data clock without an input (timeouts, pending grants, periodic re-selection)."""
        t = self._time(stamp_ns)
        return self._after(t, False)

    def beacons(self) -> dict[str, F64]:
        """Current stationary beacons and their positions."""
        states = (*DOCKED_STATES, "AT_BASE") if self.cfg.base_auvs_as_beacons else DOCKED_STATES
        return {k: r.position for k, r in self.vehicles.items() if r.state in states and r.position is not None}

    # ===================================================================== handlers =====
    def _time(self, ns: int) -> float:
        if self._t0_ns is None:
            self._t0_ns = ns
        t = (ns - self._t0_ns) * 1e-9
        self.t = max(self.t, t)
        return self.t

    def _node(self, node_id: str | None, auv_id: str, base: bool) -> F64:
        keys = [node_id] if node_id is not None else []
        if base:
            keys += [f"{self.cfg.base_node_id}/{auv_id}", self.cfg.base_node_id]
        for k in keys:
            if k in self.nodes:
                return self.nodes[k]
        raise InputRejected("unknown_node", f"{auv_id}: node {node_id!r} is not in the node table")

    def _check_status(self, msg: VehicleStatus) -> F64 | None:
        """Refusals of a status (raised before any state change); the dock position of DOCKED / AT_BASE.

        The vehicle's id names its keys (its grant, its fixes): one that is not a key chunk is refused here, before it
        can enter the registry and a decision that could never be published."""
        if not is_chunk(msg.auv_id):
            raise InputRejected("invalid_auv_id", f"vehicle id {msg.auv_id!r} is not a key chunk")
        ev = msg.event
        if ev in ("DOCKED", "AT_BASE"):
            return self._node(msg.node_id, msg.auv_id, base=ev == "AT_BASE")
        if ev == "SERVICE_DONE":
            rec = self.vehicles.get(msg.auv_id)
            state = rec.state if rec is not None else "UNKNOWN"
            if state not in (*DOCKED_STATES, "AT_BASE"):
                raise InputRejected("not_docked", f"SERVICE_DONE from {msg.auv_id} in state {state}")
        return None

    def _on_status(self, msg: VehicleStatus, t: float, pos: F64 | None) -> bool:
        rec = self.vehicles.setdefault(msg.auv_id, VehicleRecord(msg.auv_id))
        ev = msg.event
        rec.last_heard_s = t
        if ev == "DOCKED":
            rec.state, rec.node_id, rec.position = "DOCKED_SERVICING", msg.node_id, pos
            rec.route = []
            self._dequeue(msg.auv_id)
            return True
        if ev == "AT_BASE":
            rec.state, rec.node_id, rec.position = "AT_BASE", msg.node_id, pos
            rec.route = []
            self._dequeue(msg.auv_id)
            return True
        if ev == "SERVICE_DONE":
            if rec.state != "AT_BASE":
                rec.state = "DOCKED_DONE"
            if all(a != msg.auv_id for _, a in self.done_queue):
                self.done_queue.append((t, msg.auv_id))
                self.done_queue.sort()
            return False
        if ev == "DEPARTED":
            if rec.state not in ("GRANTED", "TRANSIT", "UNKNOWN"):
                self.alarms["departed_without_grant"] += 1
            rec.state = "TRANSIT"
            self._dequeue(msg.auv_id)
            self._route(rec, msg, t)
            return True
        if ev == "FAULT":
            rec.state = "FAULT"
            self._dequeue(msg.auv_id)
            return True
        # HEARTBEAT
        if rec.state == "TRANSIT":
            self._route(rec, msg, t)
        return False

    def _route(self, rec: VehicleRecord, msg: VehicleStatus, t: float) -> None:
        if msg.position_ned_m is not None:
            rec.position = np.asarray(msg.position_ned_m, dtype=np.float64)
        if msg.planned_route_ned_m:
            rec.route = [np.asarray(p, dtype=np.float64) for p in msg.planned_route_ned_m]
        if msg.speed_mps is not None:
            rec.speed_mps = msg.speed_mps
        rec.t_route_s = t

    def _dequeue(self, auv_id: str) -> None:
        self.done_queue = [(t, a) for t, a in self.done_queue if a != auv_id]

    # ===================================================================== decisions =====
    def _after(self, t: float, changed: bool) -> list[Message]:
        out: list[Message] = []
        changed |= self._timeouts(t)
        n = len(self.beacons())
        if n >= self.cfg.min_beacons:
            self.preliminary_over = True
        elif self.preliminary_over:
            self.alarms["below_min_beacons"] += int(changed)
        if changed or t - self._last_reselect >= self.cfg.reselect_period_s:
            out += self._reselect(t, exclude=self._excluded())
        out += self._try_grant(t)
        return out

    def _excluded(self) -> set[str]:
        return {self.pending[0]} if self.pending is not None else set()

    def _timeouts(self, t: float) -> bool:
        changed = False
        active = set(self.selection.members) if self.selection is not None else set()
        for k, r in self.vehicles.items():
            if r.state not in (*DOCKED_STATES, "AT_BASE"):
                continue
            limit = self.cfg.beacon_timeout_s if k in active else self.cfg.standby_timeout_s
            since = max(r.last_heard_s, self._active_since.get(k, -math.inf)) if k in active else r.last_heard_s
            if limit is not None and t - since > limit:
                r.state = "FAULT"
                self._dequeue(k)
                self.alarms["beacon_timeout"] += 1
                changed = True
        return changed

    def eval_points(self, t: float) -> F64:
        pts: list[F64] = []
        for r in self.vehicles.values():
            if r.state == "TRANSIT":
                pts += route_points(r, t, self.cfg.horizon_s, self.cfg.route_sample_m, self.cfg.eval_depth_m)
        return np.array(pts, dtype=np.float64).reshape(-1, 3)

    def _reselect(self, t: float, exclude: set[str]) -> list[Message]:
        self._last_reselect = t
        if not self.preliminary_over:
            return []  # the support vessel navigates the group until three AUVs have docked (§2.3)
        beacons = {k: v for k, v in self.beacons().items() if k not in exclude}
        m = min(self.cfg.n_followers, len(beacons) - 1)
        if m < self.cfg.n_followers and not self.cfg.allow_partial_set:
            m = 0
        if m < 1:
            if self.selection is not None:
                self.alarms["no_active_set"] += 1
                self.selection = None
            return []
        cur = self.selection.members if self.selection is not None else None
        if cur is not None and not set(cur) <= set(beacons):
            cur = None
        sel = select(beacons, self.eval_points(t), cur, self.cfg, m)
        if sel is None:
            return []
        if self.selection is not None and sel.members == self.selection.members:
            return []
        for k in sel.members:
            if self.selection is None or k not in self.selection.members:
                self._active_since[k] = t
        self.selection = sel
        self.epoch += 1
        self.assignment = BeaconAssignment(
            header=Header(stamp_ns=self._stamp(t), frame_id=self.cfg.frame_id),
            epoch=self.epoch,
            leader_id=sel.leader,
            follower_ids=list(sel.followers),
            tau_s=list(sel.tau_s),
            cycle_period_s=self.cfg.cycle_period_s,
            positions_ned_m=[beacons[k].tolist() for k in sel.members],
            cost_m=sel.cost_m if math.isfinite(sel.cost_m) else None,
            reason="below_min_beacons" if m < self.cfg.n_followers else "gdop",
        )
        return [self.assignment]

    def _stamp(self, t: float) -> int:
        return (self._t0_ns or 0) + round(t * 1e9)

    def _try_grant(self, t: float) -> list[Message]:
        out: list[Message] = []
        if self.pending is not None:
            auv, not_before, epoch = self.pending
            rec = self.vehicles[auv]
            if rec.state not in ("DOCKED_DONE", "AT_BASE") or len(self.beacons()) - 1 < self.cfg.min_beacons:
                self.pending = None  # the situation changed: start over (it stays in the queue if still done)
                return out
            heard = self.cfg.grant_on_epoch_heard and self.heard_epoch >= epoch
            if t >= not_before or heard:
                self.pending = None
                out.append(self._grant(t, auv, "reassigned"))
            return out
        head = next((a for _, a in self.done_queue if self.vehicles[a].state in ("DOCKED_DONE", "AT_BASE")), None)
        if head is None:
            return out
        others = [k for k in self.beacons() if k != head]
        if len(others) < self.cfg.min_beacons:
            return out
        if self.selection is not None and head in self.selection.members:
            out += self._reselect(t, exclude={head})
            if self.selection is not None and head in self.selection.members:
                return out  # could not re-assign away from it
            if self.cfg.grant_delay_s > 0.0:
                self.pending = (head, t + self.cfg.grant_delay_s, self.epoch)
                return out
        out.append(self._grant(t, head, "fifo"))
        return out

    def _grant(self, t: float, auv: str, reason: str) -> DepartureGrant:
        rec = self.vehicles[auv]
        rec.state = "GRANTED"
        self._dequeue(auv)
        self.grants.append((t, auv, self.epoch))
        return DepartureGrant(
            header=Header(stamp_ns=self._stamp(t), frame_id=self.cfg.frame_id),
            auv_id=auv,
            epoch=self.epoch,
            reason=reason,
        )
