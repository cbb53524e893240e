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

The filter step of a closed cycle (:meth:`RdNavCore._process_cycle`) is a short loop over components with one job
each: :mod:`.gate` (prior moments, innovation, geometry check, NIS gate), :mod:`.rescue` (one late arrival),
:mod:`.pf_update` (weights, regeneration, estimate and resampling), :mod:`.reinit_policy` (loss of lock),
:mod:`.shadow` (the EKF), :mod:`.fixes` (the RdNavFix messages); :mod:`.starter` starts a filter without a start
position and :mod:`.measurement` holds R (docs/rd_nav.md, "The filter step of one cycle").

Time: every ``*_s`` time inside is seconds on the data clock (``header.stamp_ns``) relative to the first
message seen; ``t_rx_local_s`` of the arrivals (receiver clock) is only used in differences.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import replace

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

from .assembler import CycleAssembler, OpenCycle
from .config import RdNavConfig
from .cycle import CycleData, CycleOutcome
from .dr import DeadReckoner, DrPoint
from .drift import J90, DriftModel, gm_path_var
from .ekf import EkfShadow
from .fixes import FilterState, FixBuilder, FixContent
from .gate import CycleGate, Prior
from .geometry import F64, in_window
from .initiation import Proposal
from .measurement import MeasurementModel
from .pf import ParticleFilter
from .pf_update import PfUpdater
from .reinit_policy import LossOfLock
from .rescue import LateArrivalRescue
from .shadow import ShadowUpdater
from .starter import SnapshotStarter

#: the largest ``cycles_since_update`` a fix reports (an int32; the schema and msgpack take it)
_MAX_CYCLES = 2**31 - 1


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
        # the components of the filter step (_process_cycle)
        self.model = MeasurementModel(cfg, self.drift)
        self.gate = CycleGate(cfg, self.model, self.gates)
        self.rescue = LateArrivalRescue(self.gates)
        self.pf_update = PfUpdater(cfg, self.pf, self.rng)
        self.lock = LossOfLock(cfg, self.dr, self.gates[1], self.gates_typical)
        self.shadow = ShadowUpdater(cfg, self.ekf, self.model, self.gates)
        self.fixes = FixBuilder(cfg)
        self.starter = SnapshotStarter(cfg, self.dr, self.model)
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
        self.rescue.clear()

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
            self.lock.clear()
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
        self.lock.clear()

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
        """R of §4.2 for this cycle, evaluated at the horizontal position ``at`` (:mod:`.measurement`)."""
        return self.model.cov(cd, at)

    # ====================================================================== the filter step ====
    def _process_cycle(self, oc: OpenCycle) -> list[Message]:
        """One closed cycle through the filter step (§4.4), each step a component with its maths in its module."""
        cd = self._cycle_data(oc)
        if not self.initialised:
            self._initiate(cd)
            return [cd.msg]
        if self.dr.covers(cd.t1):
            self._predict_to(cd.t1)  # step 2: DR prediction to the leader-arrival epoch t1
        prior = Prior.of(self.pf, cd, self.drift is not None and self.cfg.motion_compensation)  # Eqs. (6)-(7)
        out = CycleOutcome(reject=cd.reject, flags=list(cd.msg.flags))
        gauss = None
        if cd.reject is None:
            inn = self.gate.innovate(prior)  # e, H, S, NIS at x_hat (gate.py)
            self.gate.check_geometry(inn, out)  # CRLB DRMS, DEGRADED_GEOMETRY
            self.gate.decide(inn, prior.cd.ids, self.updates_since_seed, self.rescue, out)  # NIS gate, rescue.py
            if out.reject is None:
                gauss = inn.gaussian(prior) if out.T is None else None  # for a degenerate update
                self.pf_update.weight(prior, inn, out)  # steps 3-5 (pf_update.py)
            if out.reject is None:
                self._mark_used(prior.cd, out)
            if self.lock.counts(out):  # step 8: loss of lock (reinit_policy.py)
                self._reseed(self.lock.on_failed(prior.cd, inn, prior.x_hat), cd.t1, out)
            self.shadow.update(prior, self.updates_since_seed, out)  # §4.5 EKF shadow (shadow.py)
        else:
            self.shadow.rejected(out)
        self._tally(cd, out)
        self.pf_update.regenerate_if_degenerate(gauss, out)
        x_hat, P_hat, n_eff = self.pf_update.posterior(out, self.ekf.x, self._error_cov())  # steps 6-7
        self.status = self._status(cd.t1, out.event, out.reject, out.flags)
        return [cd.msg, *self._cycle_fixes(prior.cd, out, x_hat, P_hat, n_eff), *self._after_cycle(cd.t1)]

    def _initiate(self, cd: CycleData) -> None:
        """A cycle before the filter runs: it may start it (snapshot fixes), else only its rejection is counted."""
        if cd.reject is None:
            self._try_snapshot_start(cd)
        else:
            self.counts[f"cycle_{cd.reject}"] += 1

    def _mark_used(self, cd: CycleData, out: CycleOutcome) -> None:
        """The PF used the cycle: a complete one (M >= 2) that is well conditioned also ends the DR drift's growth
        (q_drift) and counts towards the gate's warm-up; the loss-of-lock run ends."""
        M = cd.d.size
        self.t_last_update = cd.t1
        if M >= 2:
            self.updates_since_seed += 1
        if M >= 2 and not (self.cfg.q_drift_weak_geometry and "DEGRADED_GEOMETRY" in out.flags):
            self.t_last_fix = cd.t1
        out.event = "USED"
        self.lock.on_used(out, M)

    def _reseed(self, prop: Proposal | None, t1: float, out: CycleOutcome) -> None:
        """Re-seed the PF (and the EKF) as N(X_snap, 4 P_CRLB + 0.25 I) if the loss-of-lock policy proposes it."""
        if prop is None:
            return
        self.pf.init_gaussian(prop.mean, prop.cov, self._error_cov())
        if self.cfg.ekf_reseed_on_pf_reinit:
            self.ekf.init(prop.mean, prop.cov, self._error_cov())
        self.reinit_count += 1
        self.lock.clear()
        self.t_last_update = self.t_last_fix = t1
        self.updates_since_seed = 0
        out.event = "REINIT"
        out.flags.append("REINIT")

    def _tally(self, cd: CycleData, out: CycleOutcome) -> None:
        """Count a rejected cycle by reason; remember the dropped arrival of a cycle that passed the cycle checks."""
        if out.reject is not None and out.event != "REINIT":
            self.counts[f"cycle_{out.reject}"] += 1
        if cd.reject is None:
            self.rescue.remember(out.dropped if out.event == "USED" else None)

    def _cycle_fixes(self, cd: CycleData, out: CycleOutcome, x_hat: F64, P_hat: F64, n_eff: float) -> list[Message]:
        """The PF's fix at t1 and the EKF shadow's (if it ran)."""
        used = out.event == "USED"
        ids = cd.ids
        if out.dropped is not None and used and out.dropped != cd.ids[0]:
            ids = [i for i in cd.ids if i != out.dropped]
        n_used = cd.d.size - (1 if out.dropped is not None else 0)
        state = self._state(cd.t1)
        t_local = cd.oc.leader.t_rx_local_s
        pf_fix = FixContent(
            "PF",
            "CYCLE",
            cd.t1_stamp_ns,
            x_hat,
            P_hat,
            self.status,
            n_eff,
            t_local_s=t_local,
            cycle_status="REJECTED" if not used else ("PARTIAL" if n_used == 1 else "USED"),
            reject=out.reject if not used else None,
            cd=cd,
            beacons=ids,
            residuals_m=out.residuals_m,
            nis=out.nis,
            drms_crlb_m=out.drms_crlb_m,
            flags=out.flags,
        )
        fixes: list[Message] = [self.fixes.build(pf_fix, state)]
        if out.ekf is not None:
            ekf_status, ekf_nis, ekf_resid = out.ekf
            ekf_fix = FixContent(
                "EKF",
                "CYCLE",
                cd.t1_stamp_ns,
                self.ekf.x,
                self.ekf.P,
                "TRACKING" if ekf_status == "USED" else ("REJECTED" if self.status != "LOST" else "LOST"),
                0.0,
                t_local_s=t_local,
                cycle_status=ekf_status,
                reject=None if ekf_status == "USED" else (out.reject or "NIS_GATE"),
                cd=cd,
                beacons=cd.ids,
                residuals_m=ekf_resid,
                nis=ekf_nis,
                drms_crlb_m=out.drms_crlb_m,
            )
            fixes.append(self.fixes.build(ekf_fix, state))
        return fixes

    def _after_cycle(self, t1: float) -> list[Message]:
        """With ``emit_propagated_after_cycle``: the estimate carried by DR to the latest sensor time."""
        t_now = self.dr.last_t
        if not self.cfg.emit_propagated_after_cycle or t_now is None or t_now <= t1:
            return []
        fix = self._propagated_fix(t_now)
        return [fix] if fix is not None else []

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
        # at most 2**31 - 1: a schema-valid cycle period of 1e-300 s once made 1e301 cycles, which msgpack cannot encode
        return min(max(0, math.floor((t - self.t_last_update) / self.cycle_period_s + 0.5)), _MAX_CYCLES)

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
        n = max(1, min(cfg.max_predict_steps, round((t - a.t_s) / cfg.q_step_s)))
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

    def _try_snapshot_start(self, cd: CycleData) -> None:
        """Without a start position: K consistent snapshot fixes start the filter (§4.5, [E]; starter.py)."""
        start = self.starter.offer(cd)
        if start is None:
            return
        prop, b = start
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
        content = FixContent("PF", "PROPAGATED", self._stamp(t), x, Qp, status, self.pf.n_eff())
        return self.fixes.build(content, self._state(t))

    def _state(self, t: float) -> FilterState:
        return FilterState(self.initialised, self.depth, self.reinit_count, self._cycles_since_update(t))
