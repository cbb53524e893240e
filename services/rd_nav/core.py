"""The RD-LBL navigation core of one moving AUV (digest 002 §4.4, §7.3 S3+S4+S6): ``step(msg) -> outputs``.

Inputs (existing schemas plus :mod:`schemas.rd_nav`):

* ``SpeedLog`` (DVL, body frame, ``bottom_lock``) and ``Attitude`` / ``Heading``: dead reckoning, Eq. (4);
* ``Depth``: the receiver depth z used in the 3-D ranges;
* ``SoundSpeed``: c and sigma_c (plausibility 1400-1600 m/s, else fallback with inflated sigma_c);
* ``AcousticArrival``: leader and follower packets, grouped into cycles;
* ``BeaconTable`` (node table, east/north/depth) and ``BeaconAssignment`` (expected followers, tau, T_c);
* ``VehicleStatus`` of this AUV: ``DEPARTED`` starts the filter in a disc around the dock, ``DOCKED`` stops it;
* ``NavReset``: forget the estimate.

Outputs: ``TdoaCycle`` and ``RdNavFix`` (PF, and the EKF shadow) at the leader-arrival epoch of every
closed cycle, the PF estimate carried by DR to the latest sensor time, and periodic DR-propagated fixes.
Bad input raises :class:`shared.service.InputRejected` before any state change; the filter state stays
finite with symmetric covariances.

Time: every ``*_s`` time inside is seconds on the data clock (``header.stamp_ns``) relative to the first
message seen; ``t_rx_local_s`` of the arrivals (receiver clock) is only used in differences.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.stats import chi2

from schemas import (
    AcousticArrival,
    Attitude,
    BeaconTable,
    Depth,
    Header,
    Heading,
    Message,
    NavReset,
    SoundSpeed,
    SpeedLog,
)
from schemas.rd_nav import BeaconAssignment, FollowerObs, RdNavFix, TdoaCycle, VehicleStatus
from shared.errors import InputRejected
from shared.filters.covariance import is_positive_definite, symmetrize

from .assembler import CycleAssembler, OpenCycle
from .config import RdNavConfig
from .dr import DeadReckoner, DrPoint
from .drift import J90, DriftModel, gm_path_var
from .ekf import EkfShadow
from .geometry import (
    F64,
    crlb,
    follower_units,
    gauss_newton,
    in_window,
    jacobian_d,
    measurement_cov,
    motion_comp_cov,
    multi_start_solutions,
    node_cov_term,
    predict_d,
)
from .initiation import Reinitialiser, Snapshot
from .pf import ParticleFilter


@dataclass
class CycleData:
    """The numbers of one closed cycle, ready for the filters."""

    oc: OpenCycle
    t1: float
    t1_stamp_ns: int
    ids: list[str]
    leader: F64
    followers: F64  # (M, 3) valid followers
    d: F64  # (M,)
    s: F64  # (M,)
    delta: F64  # (M, 2)
    G: F64  # (M, 2, 3) how the DR error states move delta_j (drift.py), zeros without motion compensation
    iv: F64  # (M,) variance of the trapezoid's error over each delta_j (velocity changes), m^2
    dt: F64  # (M,) receiver-clock time from the leader arrival, s
    tau: F64
    pos_sigma: F64  # (M+1,) leader first
    c: float
    sigma_c: float
    depth: float
    msg: TdoaCycle
    reject: str | None


def _cond(H: F64) -> float:
    """2-norm condition number of an M x 2 matrix from the eigenvalues of H^T H (closed form)."""
    a, b, c = float(H[:, 0] @ H[:, 0]), float(H[:, 0] @ H[:, 1]), float(H[:, 1] @ H[:, 1])
    mid, rad = 0.5 * (a + c), math.hypot(0.5 * (a - c), b)
    lo = mid - rad
    return math.sqrt((mid + rad) / lo) if lo > 0.0 else math.inf


def _finite(*vals: float) -> bool:
    return all(math.isfinite(v) for v in vals)


class RdNavCore:
    """Particle-filter RD-LBL + DR navigation of one moving AUV, with an EKF in shadow."""

    def __init__(self, config: RdNavConfig | None = None) -> None:
        self.cfg = cfg = config or RdNavConfig()
        self.rng = np.random.default_rng(cfg.seed)
        self.dr = DeadReckoner(cfg.dvl_hold_s, cfg.heading_hold_s, cfg.dr_buffer_s, cfg.dr_interpolation)
        self.asm = CycleAssembler(cfg)
        self.pf = ParticleFilter(cfg.n_particles, self.rng)
        self.ekf = EkfShadow()
        self.reinit = Reinitialiser(
            cfg.reinit_k,
            cfg.reinit_consistency_m,
            cfg.reinit_max_distance_m,
            cfg.reinit_crlb_scale,
            cfg.reinit_extra_var_m2,
            cfg.reinit_k_same_outlier,
            drift_mps=cfg.reinit_drift_sigma * math.sqrt(2.0) * cfg.sigma_dr_velocity_mps,
            strict_chain=cfg.reinit_strict_chain,
        )
        self.starter = Reinitialiser(
            cfg.reinit_k, cfg.reinit_consistency_m, math.inf, cfg.reinit_crlb_scale, cfg.reinit_extra_var_m2
        )
        self.drift: DriftModel | None = None
        if cfg.process_model == "dr_errors":
            self.drift = DriftModel(
                bias_mps=cfg.dr_speed_bias_mps,
                bias_tau_s=cfg.dr_speed_bias_tau_s,
                heading_rad=math.radians(cfg.dr_heading_sigma_deg),
                heading_tau_s=cfg.dr_heading_tau_s,
                scale=cfg.dr_speed_scale,
                scale_tau_s=cfg.dr_speed_scale_tau_s,
                speed_white_mps=cfg.dr_speed_white_mps,
                heading_white_rad=math.radians(cfg.dr_heading_white_deg),
                sample_period_s=cfg.dr_sample_period_s,
                floor_m=cfg.dr_floor_m,
                floor_path_m=cfg.dr_floor_path_m,
            )
        self.gates = {m: float(chi2.ppf(cfg.gate_probability, m)) for m in range(1, 17)}
        self.gates_typical = {m: float(chi2.ppf(0.95, m)) for m in range(1, 17)}
        self.counts: Counter[str] = Counter()  # rejected inputs and rejected cycles by reason
        self._t0_ns: int | None = None
        self._reset_state()

    def _reset_state(self) -> None:
        self.initialised = False
        self.docked = False
        self.t_state = 0.0
        self.dr_state: DrPoint | None = None
        self.t_last_update: float | None = None
        self.t_last_fix: float | None = None  # last full (M >= 2) update, re-seed or start: the DR drift grows from it
        self.updates_since_seed = 0  # complete cycles used since the start or the last re-seed
        self.status = "INIT"
        self.reinit_count = 0
        self.snapshot_starts = 0
        self.depth: float | None = self.cfg.assume_depth_m
        self.c_mps: float | None = None
        self.sigma_c_mps = self.cfg.sigma_c_fallback_mps
        self.c_fallback = False
        self._last_prop_t = -math.inf
        self._last_dropped: str | None = None

    # ======================================================================= public API =====
    def step(self, msg: Message) -> list[Message]:
        """Consume one input message; return the output messages it caused (maybe none)."""
        if isinstance(msg, AcousticArrival):
            return self._on_arrival(msg)
        if isinstance(msg, SpeedLog):
            t = self._time(msg)
            if not _finite(msg.v_forward_mps, msg.v_starboard_mps, msg.v_down_mps):
                raise InputRejected("non_finite", "SpeedLog velocity is not finite")
            self._check_dr_time(t)
            self.dr.add_velocity(t, msg.v_forward_mps, msg.v_starboard_mps, msg.v_down_mps, msg.bottom_lock)
            return self._housekeeping(t)
        if isinstance(msg, Attitude):
            t = self._time(msg)
            if not _finite(msg.heading_rad, msg.pitch_rad, msg.roll_rad):
                raise InputRejected("non_finite", "Attitude is not finite")
            self._check_dr_time(t)
            self.dr.add_attitude(t, msg.heading_rad, msg.pitch_rad, msg.roll_rad)
            return self._housekeeping(t)
        if isinstance(msg, Heading):
            t = self._time(msg)
            if not _finite(msg.heading_rad):
                raise InputRejected("non_finite", "Heading is not finite")
            self._check_dr_time(t)
            self.dr.add_heading(t, msg.heading_rad)
            return self._housekeeping(t)
        if isinstance(msg, Depth):
            t = self._time(msg)
            if not _finite(msg.depth_m):
                raise InputRejected("non_finite", "Depth is not finite")
            self.depth = msg.depth_m
            return self._housekeeping(t)
        if isinstance(msg, SoundSpeed):
            return self._on_sound_speed(msg)
        if isinstance(msg, BeaconAssignment):
            self.asm.set_assignment(msg)
            return []
        if isinstance(msg, BeaconTable):
            for b in msg.beacons:
                if not _finite(b.x_east_m, b.y_north_m, b.depth_m):
                    raise InputRejected("non_finite", f"beacon {b.beacon_id} position is not finite")
            for b in msg.beacons:
                self.asm.node_table[b.beacon_id] = np.array([b.y_north_m, b.x_east_m, b.depth_m])
            return []
        if isinstance(msg, VehicleStatus):
            return self._on_status(msg)
        if isinstance(msg, NavReset):
            self._time(msg)
            self.asm.discard_all()
            self.asm.reset_clock()
            self.reinit.clear()
            self.starter.clear()
            self._reset_state()
            return []
        raise InputRejected("unsupported_type", f"{type(msg).__name__} is not an input of rd_nav")

    @property
    def cycle_period_s(self) -> float:
        return self.asm.cycle_period_s()

    def estimate(self) -> tuple[F64, F64] | None:
        """Current PF estimate (mean, covariance) at ``t_state``, or None before initialisation."""
        return self.pf.estimate() if self.initialised else None

    # ===================================================================== input handlers =====
    def _time(self, msg: Message) -> float:
        ns = msg.header.stamp_ns
        if self._t0_ns is None:
            self._t0_ns = ns
        return (ns - self._t0_ns) * 1e-9

    def _stamp(self, t: float) -> int:
        assert self._t0_ns is not None
        return self._t0_ns + round(t * 1e9)

    def _check_dr_time(self, t: float) -> None:
        last = self.dr.last_t
        if last is not None and t < last:
            raise InputRejected("stamp_backwards", f"DR sample at {t:.3f} s precedes {last:.3f} s")

    def _on_sound_speed(self, msg: SoundSpeed) -> list[Message]:
        t = self._time(msg)
        lo, hi = self.cfg.c_plausible_mps
        if not (_finite(msg.c_mps, msg.sigma_c_mps) and lo <= msg.c_mps <= hi):
            self.c_fallback = True
            self.sigma_c_mps = self.cfg.sigma_c_fallback_mps
            raise InputRejected("implausible_sound_speed", f"c = {msg.c_mps} m/s outside [{lo}, {hi}]")
        self.c_fallback = False
        self.c_mps = msg.c_mps
        self.sigma_c_mps = max(msg.sigma_c_mps, self.cfg.sigma_c_floor_mps)
        return self._housekeeping(t)

    def _on_status(self, msg: VehicleStatus) -> list[Message]:
        t = self._time(msg)
        if msg.auv_id != self.cfg.auv_id:
            return []
        if msg.event == "DOCKED":
            self.docked = True
            self.initialised = False
            self.asm.discard_all()
            return []
        if msg.event == "DEPARTED":
            pos: F64
            if msg.position_ned_m is not None:
                pos = np.asarray(msg.position_ned_m, dtype=np.float64)
            elif msg.node_id is not None:
                pos = self.asm.node_position(self.cfg.auv_id, msg.node_id)
            else:
                raise InputRejected("no_start_position", "DEPARTED without position or known node")
            if not np.isfinite(pos).all():
                raise InputRejected("non_finite", "start position is not finite")
            last = self.dr.last_t
            if last is not None and t < last:
                raise InputRejected("stamp_backwards", f"DEPARTED at {t:.9f} s precedes DR data at {last:.9f} s")
            self.docked = False
            self._start(t, pos[:2])
        return []

    def _start(self, t: float, center: F64) -> None:
        """Initialise the cloud uniformly in a disc of radius R0 around the dock (§4.4 step 1)."""
        self.dr.advance_to(t)
        self.pf.init_disc(center, self.cfg.r0_m, self._error_cov())
        self.ekf.init(center, (self.cfg.r0_m**2 / 4.0) * np.eye(2), self._error_cov())
        self.initialised = True
        self.t_state = t
        self.dr_state = self.dr.at(t)
        self.t_last_update = None
        self.t_last_fix = t  # the start disc holds the first cycle's worth of drift
        self.updates_since_seed = 0
        self.status = "INIT"
        self.reinit.clear()

    def _on_arrival(self, msg: AcousticArrival) -> list[Message]:
        t = self._time(msg)
        if self.docked:
            self.counts["ignored_while_docked"] += 1
            return []
        pos = self.asm.check(msg, t)
        closed = self.asm.close_due(t)
        closed += self.asm.apply(msg, t, pos)
        out: list[Message] = []
        for oc in sorted(closed, key=lambda c: c.leader.t_data_s):
            out += self._process_cycle(oc)
        return out

    def _housekeeping(self, t: float) -> list[Message]:
        out: list[Message] = []
        for oc in sorted(self.asm.close_due(t), key=lambda c: c.leader.t_data_s):
            out += self._process_cycle(oc)
        lag = self.cfg.predict_lag_s
        if (
            self.drift is not None
            and self.initialised
            and not self.docked
            and t - self.t_state > lag + self.cfg.q_step_s
        ):
            self._predict_to(t - lag)  # a long gap without cycles: keep the prediction steps on the DR buffer
        period = self.cfg.propagated_fix_period_s
        if period > 0.0 and self.initialised and not self.docked and t - self._last_prop_t >= period:
            fix = self._propagated_fix(t)
            if fix is not None:
                out.append(fix)
        return out

    # ====================================================================== cycle -> data =====
    def _tau_for(self, oc: OpenCycle, rx_id: str, reported: float | None, slot: int) -> float | None:
        if self.cfg.use_reported_reply_delay and reported is not None:
            return reported
        if rx_id in oc.taus:
            return oc.taus[rx_id]
        if slot < len(self.cfg.default_tau_s):
            return self.cfg.default_tau_s[slot]
        return reported

    def _cycle_data(self, oc: OpenCycle) -> CycleData:
        cfg = self.cfg
        c = self.c_mps if self.c_mps is not None else cfg.default_c_mps
        on_fallback = self.c_mps is None or self.c_fallback
        sigma_c = cfg.sigma_c_fallback_mps if on_fallback else self.sigma_c_mps
        L = oc.leader
        t1 = L.t_data_s
        flags = list(oc.flags)
        reject = oc.reject_reason
        if on_fallback:
            flags.append("SOUND_SPEED_FALLBACK")
        obs: list[FollowerObs] = []
        ids: list[str] = []
        F: list[F64] = []
        d: list[float] = []
        s_list: list[float] = []
        dl: list[tuple[float, float]] = []
        gl: list[F64] = []
        ivl: list[float] = []
        dts: list[float] = []
        taus: list[float] = []
        sig: list[float] = [L.pos_sigma_m]
        dr_ok = self.dr.covers(t1)
        for slot, (fid, rx) in enumerate(oc.followers.items()):
            tau = self._tau_for(oc, fid, rx.reply_delay_s, slot)
            dT = rx.t_rx_local_s - L.t_rx_local_s
            r1j = math.dist(rx.pos, L.pos)
            flag: str | None = None
            s = d_j = math.nan
            delta = (0.0, 0.0)
            Gj = np.zeros((2, 3))
            iv_j = 0.0
            if tau is None:
                flag = "NO_TAU"
            else:
                s = c * (dT - tau)
                d_j = s - r1j
                if not bool(in_window(np.array([s]), np.array([r1j]), cfg.window_tol_m)[0]):
                    flag = "WINDOW_REJECT"
            if flag is None and cfg.motion_compensation and dr_ok:
                pa, pb = self.dr.at(t1), self.dr.at(t1 + dT)
                delta = (pb.x_m - pa.x_m, pb.y_m - pa.y_m)
                dXj = np.array(delta)
                Gj = np.column_stack([[pb.un_s - pa.un_s, pb.ue_s - pa.ue_s], J90 @ dXj, dXj])
                iv_j = pb.interp_var_m2 - pa.interp_var_m2
            valid = flag is None and rx.epoch == oc.epoch
            if flag is not None:
                flags.append(f"{flag}:{fid}")
            obs.append(
                FollowerObs(
                    follower_id=fid,
                    pos_ned_m=rx.pos.tolist(),
                    t_rx_local_s=rx.t_rx_local_s,
                    dT_s=dT,
                    tau_s=min(max(tau if tau is not None else 0.0, 0.0), 60.0),
                    r1j_m=r1j,
                    s_m=s if math.isfinite(s) else 0.0,
                    d_m=d_j if math.isfinite(d_j) else 0.0,
                    delta_ne_m=[delta[0], delta[1]],
                    valid=valid,
                    flag=flag,
                )
            )
            if valid:
                ids.append(fid)
                F.append(rx.pos)
                d.append(d_j)
                s_list.append(s)
                dl.append(delta)
                gl.append(Gj)
                ivl.append(iv_j)
                dts.append(dT)
                taus.append(float(tau))  # type: ignore[arg-type]
                sig.append(rx.pos_sigma_m)
        M = len(ids)
        if reject is None:
            if not dr_ok:
                reject = "DR_UNAVAILABLE"
            elif self.depth is None:
                reject = "NO_DEPTH"
            elif self.initialised and t1 < self.t_state - 1e-6:
                reject = "OUT_OF_ORDER"
            elif M == 0:
                reject = "NO_VALID_FOLLOWER"
            elif M == 1 and not cfg.use_partial_cycles:
                reject = "PARTIAL_SKIPPED"
        if M == 1 and reject is None:
            flags.append("PARTIAL")
        depth = self.depth if self.depth is not None else 0.0
        status = "REJECTED" if reject is not None else ("PARTIAL" if M == 1 else "COMPLETE")
        msg = TdoaCycle(
            header=Header(stamp_ns=L.stamp_ns, frame_id=cfg.frame_id),
            auv_id=cfg.auv_id,
            leader_id=oc.leader_id,
            cycle_seq=oc.cycle_seq,
            assignment_epoch=oc.epoch,
            t1_local_s=L.t_rx_local_s,
            leader_pos_ned_m=L.pos.tolist(),
            followers=obs,
            c_mps=c,
            sigma_c_mps=sigma_c,
            depth_m=depth,
            status=status,  # type: ignore[arg-type]
            reject_reason=reject,
            flags=flags[:32],
        )
        return CycleData(
            oc=oc,
            t1=t1,
            t1_stamp_ns=L.stamp_ns,
            ids=[oc.leader_id, *ids],
            leader=L.pos,
            followers=np.array(F).reshape(-1, 3),
            d=np.array(d, dtype=np.float64),
            s=np.array(s_list, dtype=np.float64),
            delta=np.array(dl, dtype=np.float64).reshape(-1, 2),
            G=np.array(gl, dtype=np.float64).reshape(-1, 2, 3),
            iv=np.array(ivl, dtype=np.float64),
            dt=np.array(dts, dtype=np.float64),
            tau=np.array(taus, dtype=np.float64),
            pos_sigma=np.array(sig, dtype=np.float64),
            c=c,
            sigma_c=sigma_c,
            depth=depth,
            msg=msg,
            reject=reject,
        )

    def measurement_cov(self, cd: CycleData, at: F64) -> F64:
        """R of §4.2 for this cycle, evaluated at the horizontal position ``at``."""
        cfg = self.cfg
        M = cd.d.size
        sig = np.full(M + 1, cfg.sigma_node_m)
        if cfg.use_packet_pos_sigma:
            sig = np.maximum(sig, cd.pos_sigma)
        node = None
        if np.any(sig > 0.0):
            zj = np.full(M, cd.depth)
            node = node_cov_term(at, cd.depth, zj, cd.delta, cd.leader, cd.followers, float(sig[0]), sig[1:])
        if cfg.motion_compensation and self.drift is not None:
            # the DR error states are in the filter (each particle compensates with its own): only the white DR
            # noise of the intra-cycle displacements remains, shared by two followers over the shorter one
            zj = np.full(M, cd.depth)
            u = follower_units(at, zj, cd.delta, cd.followers)
            mc: F64 = np.zeros((M, M))
            for j in range(M):
                for k in range(j, M):
                    i = j if cd.dt[j] <= cd.dt[k] else k
                    C = self.drift.white_cov(float(cd.dt[i]), cd.delta[i], cd.G[i][:, 0])
                    C = C + 0.5 * float(cd.iv[i]) * np.eye(2)
                    mc[j, k] = mc[k, j] = float(u[j] @ C @ u[k])
            node = mc if node is None else node + mc
        elif cfg.motion_compensation and cfg.sigma_dr_velocity_mps > 0.0:
            zj = np.full(M, cd.depth)
            mc = motion_comp_cov(at, zj, cd.delta, cd.followers, cd.dt, cfg.sigma_dr_velocity_mps)
            node = mc if node is None else node + mc
        sigma_c = cd.sigma_c if cfg.include_sound_speed_in_r else 0.0
        return measurement_cov(cd.s, cd.c, cfg.sigma_t_s, cfg.sigma_f_s, sigma_c, node)

    # ====================================================================== the filter step ====
    def _process_cycle(self, oc: OpenCycle) -> list[Message]:
        cd = self._cycle_data(oc)
        out: list[Message] = [cd.msg]
        if not self.initialised:
            if cd.reject is None:
                self._try_snapshot_start(cd)
            else:
                self.counts[f"cycle_{cd.reject}"] += 1
            return out
        cfg = self.cfg
        if self.dr.covers(cd.t1):
            self._predict_to(cd.t1)
        x_hat, P_hat = self.pf.estimate()
        M = cd.d.size
        zj = np.full(M, cd.depth)
        G: F64 | None = None  # DR error states -> motion compensation (process_model dr_errors)
        C_joint: F64 | None = None
        z_mean: F64 | None = None
        Hz: F64 | None = None
        gauss: tuple[F64, F64, F64, F64, F64] | None = None
        raw_delta = cd.delta
        if self.drift is not None and M > 0 and cfg.motion_compensation:
            G = cd.G
            z_mean, C_joint = self.pf.joint_estimate()
            cd = replace(cd, delta=cd.delta - np.einsum("mij,j->mi", G, z_mean[2:]))
        reject = cd.reject
        nis: float | None = None
        resid: list[float] = []
        drms_c: float | None = None
        flags = list(cd.msg.flags)
        event = ""
        ekf_state: tuple[str, float | None, list[float]] | None = None
        dropped: str | None = None
        if reject is None:
            R = self.measurement_cov(cd, x_hat)
            xr = x_hat.reshape(1, 2)
            e = cd.d - predict_d(xr, cd.leader, cd.followers, cd.delta, cd.depth, zj)[0]
            H = jacobian_d(xr, cd.leader, cd.followers, cd.delta, cd.depth, zj)[0]
            if G is not None and C_joint is not None:  # h also depends on the DR errors through delta_j
                Hz = np.hstack([H, -np.einsum("mi,mij->mj", H, G)])
                S = Hz @ C_joint @ Hz.T + R
            else:
                S = H @ P_hat @ H.T + R
            S = symmetrize(S)
            nis = nis_full = float(e @ np.linalg.solve(S, e))
            resid = e.tolist()
            if M >= 2:
                try:
                    drms_c = math.sqrt(max(float(np.trace(crlb(H, R))), 0.0))
                    if drms_c > cfg.degraded_drms_m or _cond(H) > cfg.degraded_cond:
                        flags.append("DEGRADED_GEOMETRY")
                except np.linalg.LinAlgError:
                    flags.append("DEGRADED_GEOMETRY")
            T: F64 | None = None
            rescued = False
            if not math.isfinite(nis):
                reject = "NON_FINITE_INNOVATION"
            elif cfg.gating and self.updates_since_seed < cfg.gate_after_updates:
                flags.append("UNGATED")  # converging from the start disc or a re-seed: the cloud is no judge yet
            elif cfg.gating:
                gated = nis > self.gates[min(M, 16)]
                rescue = cfg.drop_single_outlier and M >= 2 and (gated or not cfg.outlier_only_if_gated)
                late = self._one_late_arrival(e, S, cd.ids) if rescue else None
                if late is not None and late[0] == self._last_dropped:
                    late = None  # multipath is random: the same arrival late twice in a row points at the filter
                if late is not None:
                    dropped, T, nis = late
                    rescued = True
                    flags.append(f"OUTLIER:{dropped}")
                elif gated:
                    reject = "NIS_GATE"
            if reject is None:
                prior_w = self.pf.w
                if T is None:  # the cloud's moments and this cycle's linearisation, for a degenerate update
                    joint = Hz is not None and C_joint is not None and z_mean is not None
                    gauss = (z_mean, C_joint, Hz, e, S) if joint else (x_hat, P_hat, H, e, S)  # type: ignore[assignment]
                Rw = R
                if G is not None:  # each particle compensates with its mean DR errors; their shared spread adds to R
                    He = -np.einsum("mi,mij->mj", H, G)
                    Rw = R + He @ self.pf.PE @ He.T
                Rinv = np.linalg.inv(Rw if T is None else T @ Rw @ T.T)
                ok, m2_min = self.pf.weight(
                    cd.d,
                    Rinv,
                    cd.leader,
                    cd.followers,
                    raw_delta if G is not None else cd.delta,
                    cd.depth,
                    zj,
                    cfg.epsilon,
                    cfg.outlier_m2,
                    T,
                    G,
                )
                if not ok:
                    reject = "WEIGHT_FAILURE"
                elif m2_min > cfg.outlier_m2:  # no particle near the measurement: the update did nothing
                    self.pf.w = prior_w
                    reject = "NO_OVERLAP"
            if reject is None:
                self.t_last_update = cd.t1
                if M >= 2:
                    self.updates_since_seed += 1
                if M >= 2 and not (cfg.q_drift_weak_geometry and "DEGRADED_GEOMETRY" in flags):
                    self.t_last_fix = cd.t1
                event = "USED"
                if not rescued and (M >= 2 or cfg.reinit_strict_chain):
                    self.reinit.clear()  # a partial (M = 1) cycle inside the gate does not prove lock
            if (rescued or reject in ("NIS_GATE", "NO_OVERLAP")) and cfg.reinit:
                # a cycle the filter could not use whole counts towards loss of lock (§4.4 step 8)
                tag = None
                if M >= 2 and math.isfinite(nis_full):
                    # x_hat explained to measurement precision (R, not S) by one late arrival?
                    explained = self._one_late_arrival(e, R, cd.ids, self.gates_typical, cfg.reinit_late_arrival_min_m)
                    tag = explained[0] if explained is not None else None
                self.reinit.record(self._snapshot(cd, x_hat, R) if M >= 2 else None, tag)
                prop = self.reinit.propose(x_hat)
                if prop is not None:
                    self.pf.init_gaussian(prop.mean, prop.cov, self._error_cov())
                    if cfg.ekf_reseed_on_pf_reinit:
                        self.ekf.init(prop.mean, prop.cov, self._error_cov())
                    self.reinit_count += 1
                    self.reinit.clear()
                    self.t_last_update = self.t_last_fix = cd.t1
                    self.updates_since_seed = 0
                    event = "REINIT"
                    flags.append("REINIT")
            # EKF shadow: same inputs, its own gate (from the same update on as the PF's)
            if cfg.ekf_shadow and self.ekf.initialised:
                converging = self.updates_since_seed <= cfg.gate_after_updates and "UNGATED" in flags
                Re = self.measurement_cov(cd, self.ekf.x)
                ekf_res = self.ekf.update(
                    cd.d,
                    Re,
                    cd.leader,
                    cd.followers,
                    raw_delta if G is not None else cd.delta,
                    cd.depth,
                    zj,
                    self.gates[min(M, 16)] if cfg.gating and not converging else None,
                    G,
                )
                ekf_state = ("USED" if ekf_res.accepted else "REJECTED", ekf_res.nis, ekf_res.residual_m.tolist())
        else:
            ekf_state = ("REJECTED", None, []) if cfg.ekf_shadow and self.ekf.initialised else None
        if reject is not None and event != "REINIT":
            self.counts[f"cycle_{reject}"] += 1
        if cd.reject is None:
            self._last_dropped = dropped if event == "USED" else None
        if event == "USED" and gauss is not None and self.pf.n_eff() < cfg.degenerate_neff_fraction * cfg.n_particles:
            self._regenerate(*gauss)  # too few particles carry the posterior (e.g. the first cycle after the R0 disc)
            flags.append("REGENERATED")
        # estimate (Eq. 6-7) before regeneration, then regenerate (§4.4 steps 6-7)
        x_hat, P_hat = self.pf.estimate()
        if cfg.estimate == "map" and event == "USED":
            m = self.pf.map_estimate(cfg.map_weight_threshold)
            if m is not None:
                x_hat = m
        n_eff = self.pf.n_eff()
        if event == "USED" and n_eff < cfg.resample_fraction * cfg.n_particles:
            self.pf.resample(cfg.roughening_m, cfg.roughening_shrink)
        if not self.pf.finite():  # never expected; keep the state valid if it happens
            self.pf.init_gaussian(
                x_hat if np.isfinite(x_hat).all() else self.ekf.x, np.eye(2) * 100.0, self._error_cov()
            )
            flags.append("PF_RESET")
        status = self._status(cd.t1, event, reject, flags)
        self.status = status
        used = cd
        if dropped is not None and event == "USED" and dropped != cd.ids[0]:
            used = replace(cd, ids=[i for i in cd.ids if i != dropped])
        n_used = cd.d.size - (1 if dropped is not None else 0)
        cycle_status = "REJECTED" if event != "USED" else ("PARTIAL" if n_used == 1 else "USED")
        out.append(
            self._fix(
                "PF",
                "CYCLE",
                cd.t1_stamp_ns,
                cd.oc.leader.t_rx_local_s,
                x_hat,
                P_hat,
                status,
                cycle_status,
                reject if event != "USED" else None,
                used,
                n_eff,
                resid,
                nis,
                drms_c,
                flags,
                cd.t1,
            )
        )
        if ekf_state is not None:
            e_status = "TRACKING" if ekf_state[0] == "USED" else ("REJECTED" if status != "LOST" else "LOST")
            out.append(
                self._fix(
                    "EKF",
                    "CYCLE",
                    cd.t1_stamp_ns,
                    cd.oc.leader.t_rx_local_s,
                    self.ekf.x,
                    self.ekf.P,
                    e_status,
                    ekf_state[0],
                    None if ekf_state[0] == "USED" else (reject or "NIS_GATE"),
                    cd,
                    0.0,
                    ekf_state[2],
                    ekf_state[1],
                    drms_c,
                    [],
                    cd.t1,
                )
            )
        if cfg.emit_propagated_after_cycle:
            t_now = self.dr.last_t
            if t_now is not None and t_now > cd.t1:
                fix = self._propagated_fix(t_now)
                if fix is not None:
                    out.append(fix)
        return out

    def _regenerate(self, z: F64, C: F64, H: F64, e: F64, S: F64) -> None:
        """Resample, then draw the positions from the Gaussian posterior of the prior cloud's moments and this
        cycle's linearised measurement: K = C H^T S^-1, z+ = z + K e, C+ = C - K S K^T ([E]). A cloud much wider
        than one cycle's likelihood (the R0 = 10 m disc against ~0.5 m) leaves a handful of particles with weight,
        whose spread says nothing of the posterior's (nor do their few DR-error means); this keeps its covariance,
        the DR errors' included (their mean given each drawn position, and the conditional covariance)."""
        K = np.linalg.solve(S, H @ C).T
        zp = z + K @ e
        Cp = C - K @ S @ K.T
        Pxx = symmetrize(Cp[:2, :2])
        if not (np.isfinite(zp).all() and is_positive_definite(Pxx)):
            return
        self.pf.resample(0.0)
        self.pf.X = zp[:2][None, :] + self.rng.standard_normal(self.pf.X.shape) @ np.linalg.cholesky(Pxx).T
        if zp.size > 2:  # DR errors: their mean given each position, and the conditional covariance (shared)
            B = np.linalg.solve(Pxx, Cp[:2, 2:]).T  # C_ex C_xx^-1
            self.pf.E = zp[2:][None, :] + (self.pf.X - zp[:2][None, :]) @ B.T
            PE = Cp[2:, 2:] - B @ Cp[:2, 2:]
            self.pf.PE = symmetrize(PE)

    def _one_late_arrival(
        self, e: F64, S: F64, ids: list[str], rest_gates: dict[int, float] | None = None, min_delay_m: float = 0.0
    ) -> tuple[str, F64, float] | None:
        """One late arrival explains the residual (§4.11 [E]): a late follower j raises only its own d_j
        (direction u_j), a late leader lowers every d_j equally (direction -1). For each hypothesis g the
        delay estimate b = g'S^-1 e / g'S^-1 g must be positive (> min_delay_m), alone fail the 1-D gate,
        and the rest of the residual (NIS - z) pass the (M-1)-D gate.
        Returns (arrival id, transform T with T g = 0, reduced NIS)."""
        M = e.size
        rest = rest_gates or self.gates
        Si_e = np.linalg.solve(S, e)
        nis = float(e @ Si_e)
        best: tuple[float, int] | None = None
        for k in range(M + 1):  # k < M: follower k; k == M: the leader
            g = -np.ones(M) if k == M else np.eye(M)[k]
            Si_g = np.linalg.solve(S, g)
            num, den = float(g @ Si_e), float(g @ Si_g)
            z = num * num / den
            passes = num > min_delay_m * den and z > self.gates[1] and nis - z <= rest[min(M - 1, 16)]
            if passes and (best is None or z > best[0]):
                best = (z, k)
        if best is None:
            return None
        z, k = best
        if k == M:
            T = np.column_stack([-np.ones(M - 1), np.eye(M - 1)])  # d_j - d_2: leader-free differences
            return ids[0], T, nis - z
        T = np.delete(np.eye(M), k, axis=0)  # the other followers
        return ids[1 + k], T, nis - z

    def _status(self, t: float, event: str, reject: str | None, flags: list[str]) -> str:
        if not self.dr.valid_at(t):
            return "LOST"
        if event == "REINIT":
            return "REINIT"
        if event == "USED":
            return "DEGRADED_GEOMETRY" if "DEGRADED_GEOMETRY" in flags else "TRACKING"
        if self.t_last_update is None:
            return "INIT"
        if self._cycles_since_update(t) >= self.cfg.dr_only_after_cycles:
            return "DR_ONLY"
        return "REJECTED"

    def _cycles_since_update(self, t: float) -> int:
        if self.t_last_update is None:
            return 0
        return max(0, math.floor((t - self.t_last_update) / self.cycle_period_s + 0.5))

    # ====================================================================== prediction =====
    def _growth(self, a: DrPoint, b: DrPoint) -> float:
        """Diffusion variance between two DR states: n steps of q = q_rel*L/n + q_abs, plus frozen-DR growth."""
        cfg = self.cfg
        dt = b.t_s - a.t_s
        if dt <= 0.0:
            return 0.0
        n = max(1, round(dt / cfg.q_step_s))
        q = cfg.q_rel * (b.path_m - a.path_m) / n + cfg.q_abs_m
        inv = b.invalid_s - a.invalid_s
        var = n * q * q + (cfg.q_dr_invalid_mps * inv) ** 2
        if cfg.q_drift_mps > 0.0 and self.t_last_fix is not None:
            # a Gauss-Markov DR velocity error (sigma_v, tau) moves the position by its path integral since the last
            # complete, well-conditioned update: variance sigma_v^2 * 2 tau^2 (dt/tau - 1 + exp(-dt/tau)) (about
            # (sigma_v dt)^2 for dt << tau), of which the first step's q already holds one cycle's worth, so nothing
            # changes while every cycle updates the filter.
            T = cfg.q_step_s
            ta = max(a.t_s - self.t_last_fix, T)
            tb = max(b.t_s - self.t_last_fix, T)
            var += cfg.q_drift_mps**2 * max(
                gm_path_var(tb, cfg.q_drift_tau_s) - gm_path_var(ta, cfg.q_drift_tau_s), 0.0
            )
        return var

    def _predict_to(self, t: float) -> None:
        if t <= self.t_state or self.dr_state is None:
            return
        if self.drift is not None:
            self._predict_drift_to(t)
            return
        b = self.dr.at(t)
        a = self.dr_state
        dX = np.array([b.x_m - a.x_m, b.y_m - a.y_m])
        var = self._growth(a, b)
        self.pf.predict(dX, math.sqrt(var))
        if self.ekf.initialised:
            self.ekf.predict(dX, var)
        self.t_state = t
        self.dr_state = b

    def _predict_drift_to(self, t: float) -> None:
        """Prediction with the DR error model (drift.py) in steps of at most q_step_s on the DR buffer's knots."""
        assert self.drift is not None and self.dr_state is not None
        cfg = self.cfg
        a = self.dr_state
        n = max(1, round((t - a.t_s) / cfg.q_step_s))
        for k in range(1, n + 1):
            tk = t if k == n else a.t_s + (t - a.t_s) * k / n
            if k < n and not self.dr.covers(tk):
                continue  # older than the buffer: one longer step
            b = self.dr.at(tk)
            dX = np.array([b.x_m - a.x_m, b.y_m - a.y_m])
            U = np.array([b.un_s - a.un_s, b.ue_s - a.ue_s])
            step = self.drift.step(b.t_s - a.t_s, dX, U)
            inv = b.invalid_s - a.invalid_s
            extra = (cfg.q_dr_invalid_mps * inv) ** 2 + 0.5 * (b.interp_var_m2 - a.interp_var_m2)  # per axis
            if extra > 0.0:  # DR frozen (§7.4 DVL dropout); velocity changes the trapezoid smooths over
                step = replace(step, Q_white=step.Q_white + extra * np.eye(2))
            self.pf.predict_drift(dX, step)
            if self.ekf.initialised:
                self.ekf.predict_drift(dX, step)
            a = b
        self.t_state = t
        self.dr_state = a

    def _error_cov(self) -> F64 | None:
        return None if self.drift is None else self.drift.prior_cov()

    def _snapshot(self, cd: CycleData, x_hat: F64, R: F64) -> Snapshot | None:
        """Snapshot Gauss-Newton fix of one cycle (§4.5), the solution nearest x_hat."""
        cfg = self.cfg
        M = cd.d.size
        zj = np.full(M, cd.depth)
        W = np.linalg.inv(R)
        gn: dict[str, Any] = {"max_iter": cfg.gn_max_iter, "step_limit_m": cfg.gn_step_limit_m, "tol_m": cfg.gn_tol_m}
        r = gauss_newton(cd.d, x_hat.reshape(1, 2), cd.leader, cd.followers, cd.delta, cd.depth, zj, W, **gn)
        tol = 5.0 * math.sqrt(float(np.trace(R)))
        if r.converged[0] and r.residual_m[0] < tol:
            p = r.p[0]
        else:
            sols = multi_start_solutions(
                cd.d, cd.leader, cd.followers, cd.delta, cd.depth, zj, W, x_hat.reshape(1, 2), tol, **gn
            )
            if sols.shape[0] == 0:
                return None
            p = sols[int(np.argmin(np.hypot(*(sols - x_hat[None, :]).T)))]
        try:
            H = jacobian_d(p.reshape(1, 2), cd.leader, cd.followers, cd.delta, cd.depth, zj)[0]
            P = crlb(H, R)
        except np.linalg.LinAlgError:
            return None
        if not is_positive_definite(P):
            return None
        b = self.dr.at(cd.t1)
        return Snapshot(p=p.copy(), P_crlb=P, dr_xy=np.array([b.x_m, b.y_m]), t_s=cd.t1)

    def _try_snapshot_start(self, cd: CycleData) -> None:
        """Without a start position: K consistent snapshot fixes start the filter (§4.5, [E])."""
        if not self.cfg.init_from_snapshots or cd.d.size < 2:
            return
        M = cd.d.size
        zj = np.full(M, cd.depth)
        R0 = measurement_cov(cd.s, cd.c, self.cfg.sigma_t_s, self.cfg.sigma_f_s, cd.sigma_c)
        W = np.linalg.inv(R0)
        sols = multi_start_solutions(cd.d, cd.leader, cd.followers, cd.delta, cd.depth, zj, W)
        if sols.shape[0] == 0:
            self.starter.record(None)
            return
        cen = np.vstack([cd.leader[None, :2], cd.followers[:, :2]]).mean(axis=0)
        p = sols[int(np.argmin(np.hypot(*(sols - cen[None, :]).T)))]
        H = jacobian_d(p.reshape(1, 2), cd.leader, cd.followers, cd.delta, cd.depth, zj)[0]
        try:
            P = crlb(H, self.measurement_cov(cd, p))
        except np.linalg.LinAlgError:
            self.starter.record(None)
            return
        b = self.dr.at(cd.t1)
        self.starter.record(Snapshot(p=p, P_crlb=P, dr_xy=np.array([b.x_m, b.y_m])))
        prop = self.starter.propose(None)
        if prop is None:
            return
        self.pf.init_gaussian(prop.mean, prop.cov, self._error_cov())
        self.ekf.init(prop.mean, prop.cov, self._error_cov())
        self.initialised = True
        self.t_state = cd.t1
        self.dr_state = b
        self.t_last_update = self.t_last_fix = cd.t1
        self.updates_since_seed = 0
        self.status = "INIT"
        self.snapshot_starts += 1
        self.starter.clear()

    # ====================================================================== outputs =====
    def _propagated_fix(self, t: float) -> RdNavFix | None:
        if self.dr_state is None or not self.dr.covers(t):
            return None
        self._last_prop_t = t
        b = self.dr.at(t)
        a = self.dr_state
        dX = np.array([b.x_m - a.x_m, b.y_m - a.y_m])
        if self.drift is None:
            x_hat, P_hat = self.pf.estimate()
            x = x_hat + dX
            Qp = P_hat + self._growth(a, b) * np.eye(2)
        else:  # the cloud carried by DR with each particle's errors, plus the step's noise
            step = self.drift.step(b.t_s - a.t_s, dX, np.array([b.un_s - a.un_s, b.ue_s - a.ue_s]))
            Gp, Qv = self.pf.step_maps(step)
            Xp = self.pf.predicted(dX, Gp)
            x = self.pf.w @ Xp
            D = Xp - x[None, :]
            Qp = (D.T * self.pf.w) @ D + Gp @ self.pf.PE @ Gp.T + Qv
            inv = b.invalid_s - a.invalid_s
            Qp = Qp + ((self.cfg.q_dr_invalid_mps * inv) ** 2 + 0.5 * (b.interp_var_m2 - a.interp_var_m2)) * np.eye(2)
        if not self.dr.valid_at(t):
            status = "LOST"
        elif self.t_last_update is not None and self._cycles_since_update(t) >= self.cfg.dr_only_after_cycles:
            status = "DR_ONLY"
        else:
            status = self.status
        return self._fix(
            "PF",
            "PROPAGATED",
            self._stamp(t),
            None,
            x,
            Qp,
            status,
            "NONE",
            None,
            None,
            self.pf.n_eff(),
            [],
            None,
            None,
            [],
            t,
        )

    def _fix(
        self,
        estimator: str,
        kind: str,
        stamp_ns: int,
        t_local: float | None,
        x: F64,
        P: F64,
        status: str,
        cycle_status: str,
        reject: str | None,
        cd: CycleData | None,
        n_eff: float,
        resid: list[float],
        nis: float | None,
        drms_c: float | None,
        flags: list[str],
        t: float,
    ) -> RdNavFix:
        P = symmetrize(P) + 1e-9 * np.eye(2)  # a collapsed cloud still reports a positive-definite P
        return RdNavFix(
            header=Header(stamp_ns=stamp_ns, frame_id=self.cfg.frame_id),
            auv_id=self.cfg.auv_id,
            estimator=estimator,  # type: ignore[arg-type]
            kind=kind,  # type: ignore[arg-type]
            t_local_s=t_local,
            position_ned_m=[float(x[0]), float(x[1]), float(self.depth if self.depth is not None else 0.0)],
            cov_xy_m2=P.tolist(),
            status=status,  # type: ignore[arg-type]
            valid=self.initialised and status != "LOST",
            cycle_status=cycle_status,  # type: ignore[arg-type]
            reject_reason=reject,
            leader_id=cd.oc.leader_id if cd is not None else None,
            cycle_seq=cd.oc.cycle_seq if cd is not None else None,
            n_eff=float(n_eff),
            n_particles=self.cfg.n_particles if estimator == "PF" else 0,
            reinit_count=self.reinit_count,
            beacons_used=list(cd.ids) if cd is not None and cycle_status in ("USED", "PARTIAL") else [],
            residuals_m=[float(v) for v in resid],
            nis=nis if nis is None or math.isfinite(nis) else None,
            drms_crlb_m=drms_c,
            cycles_since_update=self._cycles_since_update(t),
            flags=sorted(set(flags))[:32],
        )
