"""The attitude estimator's pure core (digest 004, §2.7 and §5): one instance per radar site, state per target.

``AttitudeCore.step(msg)`` takes a :class:`~schemas.RadarPlot`, :class:`~schemas.TrackEnd` or
:class:`~schemas.RadarSite` and returns the :class:`~schemas.attitude.AttitudeEstimate` messages it produces
(one per accepted plot, plus COASTING messages when enabled). An input it refuses raises
:class:`~shared.service.InputRejected` and leaves every state untouched (covariances symmetric positive definite).
Time comes only from ``header.stamp_ns``; the core is deterministic for a given input order.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
from scipy.stats import chi2

from schemas import RadarPlot, RadarSite, TrackEnd
from schemas.attitude import CA_STATE, AttitudeEstimate, AttitudeFlag, AttitudeStatus, RawAttitudeAngles
from schemas.base import Header, StrictModel
from shared.errors import InputRejected
from shared.estimates import gaussian
from shared.filters.covariance import is_cholesky_factorable, symmetrize

from . import imm, smoother
from .angles import IDX, N_ANGLES, AngleConventions, angle_block, angle_jacobian
from .config import AttitudeConfig, MeasurementSigmas
from .filter import predict, update
from .geometry import F64, cartesian_to_spherical, convert_plot
from .initiation import fsf_condition, fsf_estimate, quadratic_state

_M = TypeVar("_M", bound=StrictModel)

#: covariance fields that skip the schema's PSD check with validate_covariances=False (the state block is built
#: unvalidated by shared.estimates.gaussian then)
_COV_FIELDS = ("angle_cov_los_deg2",)

NS = 1_000_000_000
_R2D = 180.0 / math.pi
_D2R = math.pi / 180.0


@dataclass(frozen=True)
class TrackSnapshot:
    """A copy of one target's filter state, for tests and the status queryable."""

    site_id: str
    target_id: str
    initialised: bool
    x: F64 | None
    p: F64 | None
    t_ns: int | None
    n_updates: int
    n_buffered: int
    model_probabilities: F64 | None = None  # IMM mu_j (None: the single-model filter, or not started)


class _Site:
    __slots__ = ("scan_period_s", "sigmas")

    def __init__(self, sigmas: MeasurementSigmas, scan_period_s: float) -> None:
        self.sigmas = sigmas
        self.scan_period_s = scan_period_s


class _Track:
    """Per-target state (§5.4)."""

    __slots__ = (
        "buffer",
        "coast_k",
        "imm",
        "lag",
        "n_updates",
        "nis_fail",
        "nis_hist",
        "p",
        "pending",
        "raw",
        "site_id",
        "t_activity_ns",
        "t_ns",
        "target_id",
        "x",
    )

    def __init__(self, site_id: str, target_id: str, fsf_n: int) -> None:
        self.site_id = site_id
        self.target_id = target_id
        self.buffer: deque[tuple[int, F64, F64]] = deque(maxlen=fsf_n)  # init buffer (t_ns, z, R_z)
        self.raw: deque[tuple[int, list[float]]] = deque(maxlen=3)  # last three converted plots (raw baseline)
        self.x: F64 | None = None
        self.p: F64 | None = None
        self.t_ns: int | None = None  # time of the state
        self.n_updates = 0
        self.nis_fail = 0
        self.coast_k = 0
        self.pending: list[AttitudeFlag] = []
        self.t_activity_ns = 0
        self.imm: imm.ImmState | None = None  # per-model state of the IMM (motion = "imm")
        self.lag: smoother.LagState | None = None  # the fixed-lag smoother's lagged blocks (smoother_lag_scans > 0)
        self.nis_hist: deque[float] = deque(maxlen=100)  # NIS of the accepted plots since the start

    def last_plot_ns(self) -> int | None:
        if self.x is not None:
            return self.t_ns
        return self.buffer[-1][0] if self.buffer else None

    def restart(self, t_ns: int, z: F64, rz: F64) -> None:
        """RESET: discard the state and re-enter INIT with the current plot as plot 1."""
        self.x = None
        self.p = None
        self.t_ns = None
        self.n_updates = 0
        self.nis_fail = 0
        self.coast_k = 0
        self.imm = None
        self.lag = None
        self.nis_hist.clear()
        self.buffer.clear()
        self.buffer.append((t_ns, z, rz))
        self.raw.clear()
        self.raw.append((t_ns, z.tolist()))


class AttitudeCore:
    """Heading, pitch and roll of many targets of one radar site from its plots (digest 004)."""

    def __init__(self, config: AttitudeConfig | None = None) -> None:
        self.config = config if config is not None else AttitudeConfig()
        cfg = self.config
        self.conventions = AngleConventions(g_mps2=cfg.g_mps2, los_x=cfg.los_x, roll_mode=cfg.roll_mode)
        self._d_a = cfg.jerk_variances()
        self._default_site = _Site(cfg.measurement_sigmas(), cfg.scan_period_s)
        self._sites: dict[str, _Site] = {}
        self._tracks: dict[tuple[str, str], _Track] = {}
        self._ended: dict[tuple[str, str], int] = {}
        self._t_data_ns: int | None = None
        self._t_sweep_ns: int | None = None
        self._gamma_los_idx = IDX["gamma_los"] if cfg.gamma_los_form == "paper" else IDX["gamma_los_euler"]
        self._cap_deg = cfg.sigma_cap_deg
        self._validate_cov = cfg.validate_covariances
        self._los_idx = (IDX["psi_los"], IDX["theta_los"], self._gamma_los_idx)
        # the six main angles (earth and LOS) checked against the linearisation limit
        self._main_idx = (IDX["psi"], IDX["theta"], IDX["gamma"], *self._los_idx)
        self._analytic = cfg.jacobian == "analytic"
        self._imm = cfg.motion == "imm"
        self._models = cfg.imm_models
        self._mu0 = cfg.initial_probabilities()
        self._lag = cfg.smoother_lag_scans if self._imm else 0
        #: VALID needs the mean NIS of the last W plots under the chi2(3 W) 99 % quantile / W (W = valid_nis_window)
        w = cfg.valid_nis_window
        self._nis_bound = None if w is None else float(chi2.ppf(0.99, 3 * w)) / w
        #: running counts of rejections (by reason) and events (resets, evictions), for diagnostics
        self.counters: Counter[str] = Counter()

    # ------------------------------------------------------------------ public API
    def step(self, msg: RadarPlot | TrackEnd | RadarSite) -> list[AttitudeEstimate]:
        """Process one input message; returns the estimates it produces (possibly none)."""
        if isinstance(msg, RadarPlot):
            return self._on_plot(msg)
        if isinstance(msg, TrackEnd):
            return self._on_track_end(msg)
        if isinstance(msg, RadarSite):
            return self._on_site(msg)
        raise self._reject("unsupported_input", type(msg).__name__)

    def estimate_at(self, target_id: str, stamp_ns: int, site_id: str | None = None) -> AttitudeEstimate:
        """On-demand extrapolation (§5.3): the last state moved by B(t - t_last), P by B P B^T + M, angles anew."""
        tr = self._find(target_id, site_id)
        if tr.x is None or tr.p is None or tr.t_ns is None:
            return self._init_estimate(tr, stamp_ns, "INIT", [])
        x, p = self._predict(tr, (stamp_ns - tr.t_ns) / NS)
        return self._estimate(tr, stamp_ns, x, p, ["EXTRAPOLATED"], None, None, None)

    def housekeeping(self, stamp_ns: int) -> list[AttitudeEstimate]:
        """Evict idle targets and (if enabled) emit COASTING estimates, on the data clock ``stamp_ns``."""
        cfg = self.config
        idle_ns = int(cfg.idle_timeout_s * NS)
        for key in [k for k, tr in self._tracks.items() if stamp_ns - tr.t_activity_ns > idle_ns]:
            del self._tracks[key]
            self.counters["evicted_idle"] += 1
        for key in [k for k, t in self._ended.items() if stamp_ns - t > idle_ns]:
            del self._ended[key]
        out: list[AttitudeEstimate] = []
        if not cfg.coast_output:
            return out
        for tr in self._tracks.values():
            if tr.x is None or tr.p is None or tr.t_ns is None:
                continue
            period_ns = self._site(tr.site_id).scan_period_s * NS
            while tr.coast_k < cfg.max_gap_scans and (
                stamp_ns >= tr.t_ns + (tr.coast_k + cfg.coast_after_scans) * period_ns
            ):
                tr.coast_k += 1
                t_k = tr.t_ns + round(tr.coast_k * period_ns)
                x, p = self._predict(tr, (t_k - tr.t_ns) / NS)
                out.append(self._estimate(tr, t_k, x, p, ["EXTRAPOLATED"], "COASTING", None, None))
        return out

    def snapshot(self, target_id: str, site_id: str | None = None) -> TrackSnapshot:
        """A copy of one target's state."""
        tr = self._find(target_id, site_id)
        return TrackSnapshot(
            site_id=tr.site_id,
            target_id=tr.target_id,
            initialised=tr.x is not None,
            x=None if tr.x is None else tr.x.copy(),
            p=None if tr.p is None else tr.p.copy(),
            t_ns=tr.t_ns,
            n_updates=tr.n_updates,
            n_buffered=len(tr.buffer),
            model_probabilities=None if tr.imm is None else tr.imm.mu.copy(),
        )

    def site_parameters(self, site_id: str) -> tuple[MeasurementSigmas, float]:
        """The sigmas and scan period (s) in use for a site: its last RadarSite, else the configuration's."""
        site = self._site(site_id)
        return site.sigmas, site.scan_period_s

    def targets(self) -> list[tuple[str, str]]:
        """(site_id, target_id) of every target with state, in creation order."""
        return list(self._tracks)

    # ------------------------------------------------------------------ inputs
    def _on_site(self, msg: RadarSite) -> list[AttitudeEstimate]:
        if self.config.site_id is not None and msg.site_id != self.config.site_id:
            raise self._reject("wrong_site", f"site {msg.site_id!r}, this core serves {self.config.site_id!r}")
        values = (msg.sigma_r_m, msg.sigma_az_deg, msg.sigma_el_deg, msg.scan_period_s)
        if not all(math.isfinite(v) and v > 0.0 for v in values):
            raise self._reject("bad_sigma", f"site {msg.site_id!r}: {values}")
        sig = MeasurementSigmas(sigma_r_m=msg.sigma_r_m, sigma_az_deg=msg.sigma_az_deg, sigma_el_deg=msg.sigma_el_deg)
        self._sites[msg.site_id] = _Site(sig, msg.scan_period_s)
        return []

    def _on_track_end(self, msg: TrackEnd) -> list[AttitudeEstimate]:
        if self.config.site_id is not None and msg.site_id != self.config.site_id:
            raise self._reject("wrong_site", f"site {msg.site_id!r}, this core serves {self.config.site_id!r}")
        key = (msg.site_id, msg.target_id)
        if self._tracks.pop(key, None) is not None:
            self.counters["track_end"] += 1
        self._ended[key] = msg.header.stamp_ns
        return []

    def _on_plot(self, plot: RadarPlot) -> list[AttitudeEstimate]:
        cfg = self.config
        site_id = plot.site_id
        if cfg.site_id is not None and site_id != cfg.site_id:
            raise self._reject("wrong_site", f"site {site_id!r}, this core serves {cfg.site_id!r}")
        r, az, el = plot.range_m, plot.az_deg, plot.el_deg
        if not (math.isfinite(r) and math.isfinite(az) and math.isfinite(el)):
            raise self._reject("non_finite", f"range {r}, az {az}, el {el}")
        if r <= 0.0 or abs(el) >= 90.0:
            raise self._reject("out_of_bounds", f"range {r} m, el {el} deg")
        site = self._site(site_id)
        s_r = plot.sigma_r_m if plot.sigma_r_m is not None else site.sigmas.sigma_r_m
        s_az = plot.sigma_az_deg if plot.sigma_az_deg is not None else site.sigmas.sigma_az_deg
        s_el = plot.sigma_el_deg if plot.sigma_el_deg is not None else site.sigmas.sigma_el_deg
        if not all(math.isfinite(s) and s > 0.0 for s in (s_r, s_az, s_el)):
            raise self._reject("bad_sigma", f"sigmas {s_r}, {s_az}, {s_el}")
        t = plot.header.stamp_ns
        key = (site_id, plot.target_id)
        tr = self._tracks.get(key)
        if tr is not None:
            t_prev = tr.last_plot_ns()
            if t_prev is not None:
                if abs(t - t_prev) < cfg.duplicate_time_s * NS:
                    tr.pending.append("DUPLICATE_DROPPED")
                    raise self._reject("duplicate_time", f"{plot.target_id}: stamp {t} within 1 ms of {t_prev}")
                if t < t_prev:
                    tr.pending.append("OUT_OF_ORDER_DROPPED")
                    raise self._reject("out_of_order", f"{plot.target_id}: stamp {t} before {t_prev}")

        beta = (az % 360.0) * _D2R
        eps = el * _D2R
        z, rz = convert_plot(r, beta, eps, s_r, s_az * _D2R, s_el * _D2R)
        if not (np.isfinite(z).all() and is_cholesky_factorable(rz)):  # e.g. 1 m away near the zenith, huge sigmas
            raise self._reject("degenerate_plot", f"{plot.target_id}: converted covariance not positive definite")
        los_dir = (beta, eps) if cfg.los_dir_source == "measured" else None
        period_ns = site.scan_period_s * NS
        reset_ns = cfg.reset_gap_scans * period_ns

        flags: list[AttitudeFlag] = []
        status: AttitudeStatus | None = None
        nis: float | None = None
        if tr is None:
            tr = _Track(site_id, plot.target_id, cfg.fsf_n)
            self._tracks[key] = tr
            if self._ended.pop(key, None) is not None:
                flags.append("TRACK_ID_REUSED")
                status = "RESET"
                self.counters["reset_id_reused"] += 1

        if tr.x is None or tr.p is None or tr.t_ns is None:
            if tr.buffer and t - tr.buffer[-1][0] > reset_ns:
                tr.restart(t, z, rz)
                flags.append("GAP_RESET")
                status = "RESET"
                self.counters["reset_gap"] += 1
            else:
                tr.buffer.append((t, z, rz))
                tr.raw.append((t, z.tolist()))
                if len(tr.buffer) == cfg.fsf_n and not self._fsf_start(tr, period_ns):
                    flags.append("INIT_WAITING_SPREAD")
        else:
            nis = self._kf_step(tr, t, z, rz, period_ns, flags)
            if tr.x is None:
                status = "RESET"
                nis = None
        tr.t_activity_ns = t
        tr.coast_k = 0
        flags = list(dict.fromkeys(tr.pending + flags))  # pending flags first, each once
        tr.pending = []

        out: list[AttitudeEstimate] = []
        if tr.x is not None and tr.p is not None:
            out.append(self._estimate(tr, t, tr.x, tr.p, flags, status, los_dir, nis, raw=True))
            if tr.lag is not None and tr.imm is not None and tr.t_ns == t and tr.lag.depth == self._lag:
                t_s, x_s, p_s = tr.lag.smoothed(tr.imm.mu, self._lag)
                out.append(self._estimate(tr, t_s, x_s, p_s, ["SMOOTHED"], None, None, None))
        elif cfg.emit_init:
            out.append(self._init_estimate(tr, t, status or "INIT", flags, los_dir))
        out.extend(self._advance_clock(t))
        return out

    # ------------------------------------------------------------------ filter steps
    def _fsf_start(self, tr: _Track, period_ns: float) -> bool:
        """Start the KF from the buffered plots (eq. 2) if their time spread allows; True if started."""
        cfg = self.config
        t_ref = tr.buffer[-1][0]
        taus = np.array([(b[0] - t_ref) / NS for b in tr.buffer])
        if -taus[0] * NS < cfg.fsf_min_spread_scans * period_ns or fsf_condition(taus) > cfg.fsf_max_cond:
            return False
        zs = np.stack([b[1] for b in tr.buffer])
        rs = np.stack([b[2] for b in tr.buffer])
        try:
            x, p = fsf_estimate(taus, zs, rs)
        except np.linalg.LinAlgError:
            return False
        if not (np.isfinite(x).all() and is_cholesky_factorable(p)):
            return False
        tr.x, tr.p, tr.t_ns = x, p, t_ref
        tr.n_updates = len(tr.buffer)
        tr.buffer.clear()
        if self._imm:
            tr.imm = imm.ImmState.start(x, p, self._mu0, self._models)
            if self._lag:
                tr.lag = smoother.LagState.empty(len(self._models), tr.imm.xs.shape[1])
        return True

    def _predict(self, tr: _Track, dt_s: float) -> tuple[F64, F64]:
        """The state's (mixture's) prediction over dt_s: B alpha, B P B^T + M, or the IMM's predicted moments."""
        assert tr.x is not None and tr.p is not None
        if tr.imm is not None:
            x, p = imm.predict_combined(tr.imm, self._models, dt_s)
            return x[:9], p[:9, :9]
        return predict(tr.x, tr.p, dt_s, self._d_a)

    def _kf_step(
        self, tr: _Track, t: int, z: F64, rz: F64, period_ns: float, flags: list[AttitudeFlag]
    ) -> float | None:
        """Predict and update (eq. 3) with gap, gate and covariance checks; may RESET the track."""
        assert tr.x is not None and tr.p is not None and tr.t_ns is not None
        cfg = self.config
        if t - tr.t_ns > cfg.reset_gap_scans * period_ns:
            tr.restart(t, z, rz)
            flags.append("GAP_RESET")
            self.counters["reset_gap"] += 1
            return None
        if tr.imm is not None:
            return self._imm_step(tr, t, z, rz, period_ns, flags)
        x_pred, p_pred = predict(tr.x, tr.p, (t - tr.t_ns) / NS, self._d_a, symmetrise=False)
        try:
            x, p, nis = update(x_pred, p_pred, z, rz)
        except np.linalg.LinAlgError:
            tr.restart(t, z, rz)
            flags.append("COVARIANCE_RESET")
            self.counters["reset_covariance"] += 1
            return None
        if cfg.nis_gate is not None and not nis <= cfg.nis_gate and self._gate_failed(tr, t, z, rz, nis, flags):
            return None
        if not (np.isfinite(x).all() and is_cholesky_factorable(p)):
            tr.restart(t, z, rz)
            flags.append("COVARIANCE_RESET")
            self.counters["reset_covariance"] += 1
            return None
        self._accept(tr, t, z, x, p, nis, flags, period_ns)
        return nis

    def _accept(
        self, tr: _Track, t: int, z: F64, x: F64, p: F64, nis: float, flags: list[AttitudeFlag], period_ns: float
    ) -> None:
        """The plot is in the state: store the estimate, count it, remember its NIS and the raw plot."""
        assert tr.t_ns is not None
        if t - tr.t_ns > self.config.coast_after_scans * period_ns:
            flags.append("SCANS_MISSED")  # predicted over the gap (§5.6): the covariance grew through M
            self.counters["scans_missed"] += 1
        tr.x, tr.p, tr.t_ns = x, p, t
        tr.n_updates += 1
        tr.nis_fail = 0
        tr.nis_hist.append(nis)
        tr.raw.append((t, z.tolist()))

    def _gate_failed(self, tr: _Track, t: int, z: F64, rz: F64, nis: float, flags: list[AttitudeFlag]) -> bool:
        """A plot outside the gate: count it; True if the track was reset, else raises InputRejected."""
        tr.nis_fail += 1
        if tr.nis_fail >= self.config.nis_reset_count:
            tr.restart(t, z, rz)
            flags.append("NIS_RESET")
            self.counters["reset_nis"] += 1
            return True
        tr.pending.append("GATE_REJECTED")
        raise self._reject("innovation_gate", f"{tr.target_id}: NIS {nis:.1f} > {self.config.nis_gate} ({tr.nis_fail})")

    def _imm_step(
        self, tr: _Track, t: int, z: F64, rz: F64, period_ns: float, flags: list[AttitudeFlag]
    ) -> float | None:
        """One IMM cycle (imm.py) with the manoeuvre gate; may RESET the track like the single-model step."""
        assert tr.imm is not None
        cfg = self.config
        dt = (t - tr.t_ns) / NS if tr.t_ns is not None else 0.0
        c, xp, pp = imm.predict(tr.imm, self._models, dt)
        try:
            res: imm.ImmUpdate | None = imm.update_models(c, xp, pp, z, rz, self._models)
        except np.linalg.LinAlgError:
            res = None
        # the gate statistic is at most the smallest per-model NIS (the widening only enlarges S): compute it only
        # when that NIS is outside the gate
        if cfg.nis_gate is not None and not (res is not None and float(res.nis_models.min()) <= cfg.nis_gate):
            widen = 0.0 if cfg.gate_accel_mps2 is None else 0.5 * cfg.gate_accel_mps2 * dt * dt
            try:
                g = imm.gate_nis(xp, pp, z, rz, widen)
            except np.linalg.LinAlgError:
                g = math.nan
            if not g <= cfg.nis_gate and self._gate_failed(tr, t, z, rz, g, flags):
                return None
        if res is None or not (np.isfinite(res.x).all() and is_cholesky_factorable(res.p)):
            tr.restart(t, z, rz)
            flags.append("COVARIANCE_RESET")
            self.counters["reset_covariance"] += 1
            return None
        if tr.lag is not None and tr.t_ns is not None:
            try:
                tr.lag = smoother.step(tr.lag, tr.imm, self._models, dt, xp, pp, z, rz, res.state, tr.t_ns, self._lag)
            except np.linalg.LinAlgError:  # not expected (the IMM's own update factorised the same S): start over
                tr.lag = smoother.LagState.empty(len(self._models), res.state.xs.shape[1])
        tr.imm = res.state
        # the output is the 9-state of eq. (3) (a CT model's turn rate, index 9, is internal to the IMM)
        self._accept(tr, t, z, res.x[:9].copy(), res.p[:9, :9].copy(), res.nis, flags, period_ns)
        return res.nis

    # ------------------------------------------------------------------ outputs
    def _header(self, tr: _Track, stamp_ns: int) -> Header:
        return self._new(
            Header, stamp_ns=stamp_ns, frame_id=self.config.frame_id_prefix + tr.site_id, source=self.config.source
        )

    def _new(self, cls: type[_M], **fields: Any) -> _M:
        """Build an output model, validated; with validate_covariances=False the covariance fields skip the
        schema's O(n^3) PSD check (they are symmetric PSD by construction here) and everything else is validated."""
        if self._validate_cov or cls is not AttitudeEstimate:
            return cls(**fields)
        covs = {k: fields.pop(k) for k in _COV_FIELDS if k in fields}
        return cls(**fields).model_copy(update=covs)

    def _init_estimate(
        self,
        tr: _Track,
        stamp_ns: int,
        status: AttitudeStatus,
        flags: list[AttitudeFlag],
        los_dir: tuple[float, float] | None = None,
    ) -> AttitudeEstimate:
        alpha_raw = self._raw_state(tr)
        raw = None if alpha_raw is None else self._raw_message(alpha_raw, los_dir)
        return self._new(
            AttitudeEstimate,
            header=self._header(tr, stamp_ns),
            site_id=tr.site_id,
            target_id=tr.target_id,
            status=status,
            n_updates=len(tr.buffer),
            los_x=self.config.los_x,
            gamma_los_form=self.config.gamma_los_form,
            flags=flags,
            raw=raw,
        )

    def _raw_output(self, tr: _Track, los_dir: tuple[float, float] | None) -> RawAttitudeAngles | None:
        alpha_raw = self._raw_state(tr)
        return None if alpha_raw is None else self._raw_message(alpha_raw, los_dir)

    def _raw_state(self, tr: _Track) -> list[float] | None:
        """The raw baseline of §2.6: the 3-point FSF through the last three converted plots (None if unavailable)."""
        cfg = self.config
        if not cfg.raw_output or len(tr.raw) < 3:
            return None
        t_ref = tr.raw[-1][0]
        if t_ref - tr.raw[0][0] < cfg.fsf_min_spread_scans * self._site(tr.site_id).scan_period_s * NS:
            return None
        return quadratic_state([(t - t_ref) / NS for t, _ in tr.raw], [z for _, z in tr.raw])

    def _raw_message(self, alpha: list[float], los_dir: tuple[float, float] | None) -> RawAttitudeAngles:
        """Raw-baseline angles -> message; undefined per the v_min and normal-force rules only (no sigmas)."""
        cfg = self.config
        vals, _, kin = angle_block(alpha, self.conventions, los_dir, jacobian=False)
        h_ok = kin.v_h > 0.0 and kin.v_h >= cfg.v_min_mps
        p_ok = kin.speed > 0.0 and kin.speed >= cfg.v_min_mps
        r_ok = h_ok and math.isfinite(kin.load_factor) and abs(kin.load_factor) >= cfg.min_normal_force_g
        ok = (h_ok, p_ok, r_ok, h_ok, h_ok, r_ok, r_ok, r_ok, r_ok, h_ok)
        v = [a * _R2D if ok[n] and math.isfinite(a) else None for n, a in enumerate(vals)]
        return self._new(
            RawAttitudeAngles,
            psi_deg=v[0],
            theta_deg=v[1],
            gamma_deg=v[2],
            psi_los_deg=v[3],
            theta_los_deg=v[4],
            gamma_los_deg=v[self._gamma_los_idx],
            gamma_los_euler_deg=v[6],
            aspect_az_deg=v[7],
            aspect_el_deg=v[8],
            aspect_total_deg=v[9],
        )

    def _estimate(
        self,
        tr: _Track,
        stamp_ns: int,
        x: F64,
        p: F64,
        flags: list[AttitudeFlag],
        status: AttitudeStatus | None,
        los_dir: tuple[float, float] | None,
        nis: float | None,
        raw: bool = False,
    ) -> AttitudeEstimate:
        """Angle block (§2.5) on a state: angles, linearised sigmas, validity flags and status (§5.5)."""
        cfg = self.config
        xl = x.tolist()
        vals, jac, kin = angle_block(xl, self.conventions, los_dir, jacobian=self._analytic)
        if not self._analytic:
            jac = angle_jacobian(x, self.conventions, cfg.jacobian_steps, los_dir)[1]
        if jac is None:  # no LOS geometry (V_h = 0 or target overhead): every angle is undefined anyway
            jac = np.zeros((N_ANGLES, 9))
        var = ((jac @ p) * jac).sum(axis=1).tolist()  # diag(J P J^T), rad^2
        sig = [math.sqrt(v) * _R2D if v > 0.0 else (0.0 if v == 0.0 else math.nan) for v in var]
        a = [v * _R2D for v in vals]
        vh, speed, load = kin.v_h, kin.speed, kin.load_factor
        flags = list(flags)
        heading_ok = vh > 0.0 and vh >= cfg.v_min_mps
        if heading_ok and cfg.heading_sigma_factor > 0.0:
            c, s_ = xl[1] / vh, xl[7] / vh
            var_vh = c * c * p[1, 1] + 2.0 * c * s_ * p[1, 7] + s_ * s_ * p[7, 7]
            heading_ok = vh >= cfg.heading_sigma_factor * math.sqrt(max(float(var_vh), 0.0))
        pitch_ok = speed > 0.0 and speed >= cfg.v_min_mps
        roll_ok = heading_ok and math.isfinite(load) and abs(load) >= cfg.min_normal_force_g
        if not heading_ok:
            flags.append("HEADING_UNDEFINED")
        if not pitch_ok:
            flags.append("PITCH_UNDEFINED")
        if not roll_ok:
            flags.append("ROLL_UNDEFINED")
        kinds = (heading_ok, pitch_ok, roll_ok, heading_ok, heading_ok, roll_ok, roll_ok, roll_ok, roll_ok, heading_ok)
        ok = [o and math.isfinite(a[i]) and math.isfinite(sig[i]) for i, o in enumerate(kinds)]

        lin_max = cfg.linearisation_sigma_max_deg
        invalid = tr.n_updates < cfg.min_updates_valid or any(ok[i] and sig[i] > lin_max for i in self._main_idx)
        cap = self._cap_deg
        sig_out = [min(v, cap) for v in sig] if invalid else sig
        if invalid:
            flags.append("LINEARISATION_INVALID")
        g_idx = self._gamma_los_idx
        los_idx = self._los_idx
        if status is None:
            valid = not invalid and all(ok[i] and sig[i] <= cfg.valid_sigma_deg for i in los_idx)
            if valid and self._nis_bound is not None:
                w = cfg.valid_nis_window or 1
                recent = list(tr.nis_hist)[-w:]
                valid = len(recent) == w and sum(recent) / w <= self._nis_bound
            status = "VALID" if valid else "CONVERGING"

        v = [a[i] if ok[i] else None for i in range(N_ANGLES)]
        sd = [sig_out[i] if ok[i] else None for i in range(N_ANGLES)]
        cov_los: list[list[float]] | None = None
        if ok[los_idx[0]] and ok[los_idx[1]] and ok[los_idx[2]]:
            jl = jac[list(los_idx)]
            c3 = jl @ p @ jl.T
            c3 = symmetrize(c3) * (_R2D * _R2D)
            if invalid:
                scale = np.array([min(1.0, cap / sig[i]) if sig[i] > 0.0 else 1.0 for i in los_idx])
                c3 = c3 * np.outer(scale, scale)
            cov_los = c3.tolist()

        r_m, beta, eps = cartesian_to_spherical(x[0::3])
        return self._new(
            AttitudeEstimate,
            header=self._header(tr, stamp_ns),
            site_id=tr.site_id,
            target_id=tr.target_id,
            status=status,
            n_updates=tr.n_updates,
            los_x=cfg.los_x,
            gamma_los_form=cfg.gamma_los_form,
            psi_deg=v[0],
            theta_deg=v[1],
            gamma_deg=v[2],
            sigma_psi_deg=sd[0],
            sigma_theta_deg=sd[1],
            sigma_gamma_deg=sd[2],
            psi_los_deg=v[3],
            theta_los_deg=v[4],
            gamma_los_deg=v[g_idx],
            gamma_los_euler_deg=v[6],
            sigma_psi_los_deg=sd[3],
            sigma_theta_los_deg=sd[4],
            sigma_gamma_los_deg=sd[g_idx],
            sigma_gamma_los_euler_deg=sd[6],
            angle_cov_los_deg2=cov_los,
            aspect_az_deg=v[7],
            aspect_el_deg=v[8],
            aspect_total_deg=v[9],
            sigma_aspect_az_deg=sd[7],
            sigma_aspect_el_deg=sd[8],
            sigma_aspect_total_deg=sd[9],
            range_m=r_m,
            az_deg=beta * _R2D,
            el_deg=eps * _R2D,
            estimate=gaussian(
                self.config.frame_id_prefix + tr.site_id, CA_STATE, xl, p.tolist(), validate=self._validate_cov
            ),
            speed_mps=speed,
            turn_rate_dps=kin.psi_dot * _R2D if heading_ok else None,
            load_factor=load if heading_ok and pitch_ok and math.isfinite(load) else None,
            nis=nis,
            model_probabilities=None if tr.imm is None else tr.imm.mu.tolist(),
            flags=flags,
            raw=self._raw_output(tr, los_dir) if raw else None,
        )

    # ------------------------------------------------------------------ helpers
    def _site(self, site_id: str) -> _Site:
        return self._sites.get(site_id, self._default_site)

    def _find(self, target_id: str, site_id: str | None) -> _Track:
        site = site_id if site_id is not None else self.config.site_id
        if site is not None:
            tr = self._tracks.get((site, target_id))
            if tr is None:
                raise self._reject("unknown_target", f"{site}/{target_id}")
            return tr
        found = [tr for (s, t), tr in self._tracks.items() if t == target_id]
        if len(found) != 1:
            raise self._reject("unknown_target", f"{target_id}: {len(found)} matches; give site_id")
        return found[0]

    def _advance_clock(self, t_ns: int) -> Iterable[AttitudeEstimate]:
        if self._t_data_ns is None or t_ns > self._t_data_ns:
            self._t_data_ns = t_ns
        if self._t_sweep_ns is None:
            self._t_sweep_ns = self._t_data_ns
            return []
        if self._t_data_ns - self._t_sweep_ns < self.config.housekeeping_interval_s * NS:
            return []
        self._t_sweep_ns = self._t_data_ns
        return self.housekeeping(self._t_data_ns)

    def _reject(self, reason: str, detail: str) -> InputRejected:
        self.counters[reason] += 1
        return InputRejected(reason, detail)
