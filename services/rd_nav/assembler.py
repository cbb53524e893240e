"""Cycle assembly from acoustic arrivals (digest §7.3 S3 and the bad-input table §7.4).

Groups ``AcousticArrival`` by (leader_id, cycle_seq). Checks every packet (known sender and node, broadcast
position within ``pos_check_tol_m`` of the node table, no duplicates, no late packets of a closed cycle, no
follower without its leader), tracks the receiver clock against the data clock to detect clock jumps, and
closes a cycle when every expected follower has arrived or at ``t1 + max_j(tau_j + 2 r_1j/c) + T_pkt + margin``.

Clock model: ``offset = t_rx_local_s - stamp_s`` relates the receiver (modem) clock to the data clock of
the DR sensors. It changes slowly with skew; a step larger than ``clock_jump_tol_s`` (or a decreasing
``t_rx_local_s``) is a clock jump: every open cycle spanning it is discarded and the offset re-anchored.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np

from schemas import AcousticArrival
from schemas.rd_nav import BeaconAssignment
from shared.errors import InputRejected

from .config import RdNavConfig
from .geometry import F64


@dataclass(frozen=True)
class Rx:
    """One accepted arrival."""

    sender_id: str
    kind: str
    t_rx_local_s: float
    stamp_ns: int
    t_data_s: float
    pos: F64  # surveyed position from the node table (never the broadcast one), NED m
    pos_sigma_m: float
    reply_delay_s: float | None
    epoch: int


@dataclass
class OpenCycle:
    """A cycle being assembled (and, once closed, handed to the estimator)."""

    leader_id: str
    cycle_seq: int
    epoch: int
    leader: Rx
    offset_s: float
    deadline_s: float
    expected: list[str] | None
    taus: dict[str, float]
    followers: dict[str, Rx] = field(default_factory=dict)
    flags: list[str] = field(default_factory=list)
    reject_reason: str | None = None


class CycleAssembler:
    """S3 cycle assembler of one moving AUV."""

    def __init__(self, cfg: RdNavConfig) -> None:
        self.cfg = cfg
        self.node_table: dict[str, F64] = {k: np.array(v, dtype=np.float64) for k, v in cfg.node_table_ned_m.items()}
        self.assignments: dict[int, BeaconAssignment] = {}
        self.open: dict[tuple[str, int], OpenCycle] = {}
        self._closed: deque[tuple[str, int]] = deque(maxlen=256)
        self._closed_set: set[tuple[str, int]] = set()
        self.offset_s: float | None = None
        self.last_t_rx: float | None = None
        self.counts: Counter[str] = Counter()

    # ----- configuration inputs ---------------------------------------------------------------
    def set_assignment(self, a: BeaconAssignment) -> None:
        self.assignments[a.epoch] = a
        for old in sorted(self.assignments)[:-8]:
            del self.assignments[old]

    def cycle_period_s(self) -> float:
        if self.assignments:
            return self.assignments[max(self.assignments)].cycle_period_s
        return self.cfg.cycle_period_s

    def reset_clock(self) -> None:
        self.offset_s = None
        self.last_t_rx = None

    # ----- packet checks (no state change; raise InputRejected) ------------------------------
    def node_position(self, sender_id: str, node_id: str | None) -> F64:
        keys = [node_id] if node_id is not None else [f"{self.cfg.base_node_id}/{sender_id}", self.cfg.base_node_id]
        for k in keys:
            if k in self.node_table:
                return self.node_table[k]
        raise InputRejected("unknown_node", f"{sender_id}: node {node_id!r} is not in the node table")

    def check(self, arr: AcousticArrival, t_data: float) -> F64:
        """Validate one arrival; returns the surveyed position of its sender's node."""
        pk = arr.packet
        if arr.receiver_id != self.cfg.auv_id:
            raise InputRejected("wrong_receiver", f"{arr.receiver_id} is not {self.cfg.auv_id}")
        if not (math.isfinite(arr.t_rx_local_s) and all(math.isfinite(v) for v in pk.pos_ned_m)):
            raise InputRejected("non_finite", "arrival time or position is not finite")
        if (pk.kind == "LEADER") != (pk.sender_id == pk.leader_id):
            raise InputRejected("bad_packet", f"{pk.kind} packet from {pk.sender_id} names leader {pk.leader_id}")
        if self.cfg.fleet_ids and pk.sender_id not in self.cfg.fleet_ids:
            raise InputRejected("unknown_sender", f"{pk.sender_id} is not a known vehicle")
        pos = self.node_position(pk.sender_id, pk.node_id)
        mismatch = math.dist(pk.pos_ned_m, pos)
        if not mismatch <= self.cfg.pos_check_tol_m:
            raise InputRejected(
                "beacon_pos_mismatch", f"{pk.sender_id} broadcasts a position {mismatch:.2f} m off node {pk.node_id}"
            )
        key = (pk.leader_id, pk.cycle_seq)
        oc = self.open.get(key)
        if oc is not None and oc.deadline_s < t_data:
            oc = None  # due: it closes before this arrival is applied
            stale = True
        else:
            stale = key in self._closed_set
        if pk.kind == "LEADER":
            if oc is not None:
                raise InputRejected("duplicate", f"second LEADER packet of {key}")
            if stale:
                raise InputRejected("stale_packet", f"LEADER packet of closed cycle {key}")
        else:
            if oc is None:
                if stale:
                    raise InputRejected("stale_packet", f"{pk.sender_id} reply to closed cycle {key}")
                raise InputRejected("no_leader", f"{pk.sender_id} reply to {key} without its leader packet")
            if pk.sender_id in oc.followers:
                raise InputRejected("duplicate", f"second reply of {pk.sender_id} in {key}")
            if oc.expected is not None and pk.assignment_epoch == oc.epoch and pk.sender_id not in oc.expected:
                raise InputRejected("unassigned_follower", f"{pk.sender_id} is not a follower of epoch {oc.epoch}")
        return pos

    # ----- state changes ----------------------------------------------------------------------
    def close_due(self, t_data: float) -> list[OpenCycle]:
        due = [oc for oc in self.open.values() if oc.deadline_s < t_data]
        for oc in due:
            self._close(oc)
        return due

    def apply(self, arr: AcousticArrival, t_data: float, pos: F64) -> list[OpenCycle]:
        """Apply a checked arrival; returns the cycles it closed (complete, or discarded by a clock jump)."""
        pk = arr.packet
        closed: list[OpenCycle] = []
        offset = arr.t_rx_local_s - t_data
        tol = self.cfg.clock_jump_tol_s
        jump = self.offset_s is not None and abs(offset - self.offset_s) > tol
        if self.last_t_rx is not None and arr.t_rx_local_s < self.last_t_rx - tol:
            jump = True
        rx = Rx(
            sender_id=pk.sender_id,
            kind=pk.kind,
            t_rx_local_s=arr.t_rx_local_s,
            stamp_ns=arr.header.stamp_ns,
            t_data_s=t_data,
            pos=pos,
            pos_sigma_m=pk.pos_sigma_m,
            reply_delay_s=pk.reply_delay_s,
            epoch=pk.assignment_epoch,
        )
        key = (pk.leader_id, pk.cycle_seq)
        if jump:
            self.counts["clock_jump"] += 1
            for oc in list(self.open.values()):
                if pk.kind == "FOLLOWER" and oc.leader_id == pk.leader_id and oc.cycle_seq == pk.cycle_seq:
                    oc.followers[pk.sender_id] = rx
                oc.reject_reason = "CLOCK_JUMP"
                oc.flags.append("CLOCK_JUMP")
                self._close(oc)
                closed.append(oc)
        self.offset_s = offset
        self.last_t_rx = arr.t_rx_local_s
        if pk.kind == "LEADER":
            self.open[key] = self._new_cycle(rx, pk.leader_id, pk.cycle_seq, offset)
            return closed
        cur = self.open.get(key)
        if cur is None:  # its cycle was discarded by the jump just detected
            return closed
        oc = cur
        oc.followers[pk.sender_id] = rx
        if pk.assignment_epoch != oc.epoch and "MIXED_EPOCH" not in oc.flags:
            oc.flags.append("MIXED_EPOCH")
            oc.reject_reason = "MIXED_EPOCH"
        if oc.expected is not None and set(oc.expected) <= set(oc.followers):
            self._close(oc)
            closed.append(oc)
        return closed

    def _new_cycle(self, rx: Rx, leader_id: str, seq: int, offset: float) -> OpenCycle:
        a = self.assignments.get(rx.epoch)
        expected: list[str] | None = None
        taus: dict[str, float] = {}
        span = self.cfg.max_cycle_span_s
        if a is not None and a.leader_id == leader_id:
            expected = list(a.follower_ids)
            taus = dict(zip(a.follower_ids, a.tau_s, strict=True))
            c_min = self.cfg.c_plausible_mps[0]
            pos = [self.node_table_position_of(fid, a) for fid in a.follower_ids]
            if all(p is not None for p in pos):
                worst = max(
                    tau + 2.0 * float(np.linalg.norm(p - rx.pos)) / c_min
                    for tau, p in zip(a.tau_s, pos, strict=True)
                    if p is not None
                )
                span = worst + self.cfg.t_pkt_s + self.cfg.close_margin_s
        return OpenCycle(
            leader_id=leader_id,
            cycle_seq=seq,
            epoch=rx.epoch,
            leader=rx,
            offset_s=offset,
            deadline_s=rx.t_data_s + span,
            expected=expected,
            taus=taus,
        )

    @staticmethod
    def node_table_position_of(auv_id: str, a: BeaconAssignment) -> F64 | None:
        members = [a.leader_id, *a.follower_ids]
        if a.positions_ned_m and auv_id in members:
            return np.asarray(a.positions_ned_m[members.index(auv_id)], dtype=np.float64)
        return None

    def _close(self, oc: OpenCycle) -> None:
        key = (oc.leader_id, oc.cycle_seq)
        self.open.pop(key, None)
        if len(self._closed) == self._closed.maxlen:
            self._closed_set.discard(self._closed[0])
        self._closed.append(key)
        self._closed_set.add(key)

    def discard_all(self) -> None:
        for oc in list(self.open.values()):
            self._close(oc)
