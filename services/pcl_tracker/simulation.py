"""Pure truth + measurement simulation for the PCL tracker (digest 003 §3.1, §4.4 E5).

Targets fly straight or with a horizontal coordinated turn; each scan yields one
:class:`~schemas.radar.BistaticScan` (empty scans too) with Gaussian noise on (r_b, a, e, v_b), detection
probability P_d and Poisson clutter, plus :class:`~schemas.truth.Truth` messages. Time comes from
``header.stamp_ns``; all randomness from the ``numpy.random.Generator`` passed in, so a player plugin can
wrap this later.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from schemas.base import Header
from schemas.radar import BistaticPlot, BistaticScan
from schemas.truth import Truth
from shared.filters.angles import wrap_pi

from .config import SPEED_OF_LIGHT_MPS, GeometryConfig, PclTrackerConfig
from .geometry import FloatArray, h_b

#: paper geometry and target (digest §3.1)
PAPER_TX_M = (8000.0, 0.0, 300.0)
PAPER_P0_M = (9000.0, 5000.0, 1000.0)
PAPER_SPEED_MPS = 200.0
PAPER_COURSE_DEG = 256.0
PAPER_SIGMA = (200.0, 0.5, 0.5, 5.0)  # r_b m, az deg, el deg, v_b m/s


@dataclass(frozen=True)
class TargetSpec:
    """One target: straight flight with an optional horizontal coordinated turn between two times."""

    target_id: str
    p0_m: tuple[float, float, float]
    v0_mps: tuple[float, float, float]
    t_birth_s: float = 0.0
    t_death_s: float = math.inf
    turn_rate_dps: float = 0.0  # > 0: clockwise seen from above (course increases)
    turn_start_s: float = 0.0
    turn_end_s: float = math.inf

    def state(self, t: float) -> FloatArray | None:
        """True [x, y, z, vx, vy, vz] at time t (s), or None outside [t_birth, t_death]."""
        if t < self.t_birth_s or t > self.t_death_s:
            return None
        p = np.array(self.p0_m, dtype=np.float64)
        v = np.array(self.v0_mps, dtype=np.float64)
        dt = t - self.t_birth_s
        w = math.radians(self.turn_rate_dps)
        if w == 0.0:
            return np.concatenate([p + v * dt, v])
        ts = max(self.turn_start_s - self.t_birth_s, 0.0)
        te = max(self.turn_end_s - self.t_birth_s, ts)
        # straight leg before the turn
        d1 = min(dt, ts)
        p = p + v * d1
        if dt <= ts:
            return np.concatenate([p, v])
        # turn leg
        d2 = min(dt, te) - ts
        V = math.hypot(v[0], v[1])
        th0 = math.atan2(v[0], v[1])
        th = th0 + w * d2
        p = p + np.array(
            [(V / w) * (math.cos(th0) - math.cos(th)), (V / w) * (math.sin(th) - math.sin(th0)), v[2] * d2]
        )
        v = np.array([V * math.sin(th), V * math.cos(th), v[2]])
        if dt <= te:
            return np.concatenate([p, v])
        return np.concatenate([p + v * (dt - te), v])


@dataclass(frozen=True)
class ClutterSpec:
    """Uniform Poisson clutter in the bistatic measurement box (digest §4.4 E5 defaults)."""

    rate_per_scan: float = 0.0
    rb_range_m: tuple[float, float] = (0.0, 50_000.0)
    az_range_deg: tuple[float, float] = (-180.0, 180.0)
    el_range_deg: tuple[float, float] = (0.0, 30.0)
    vb_range_mps: tuple[float, float] = (-450.0, 450.0)


@dataclass(frozen=True)
class SnrSpec:
    """Signal-to-noise ratio of the plots [E].

    ``fixed`` (the default): 20 dB for target plots, 13 dB for clutter. ``swerling1``: a square-law detector
    with threshold ``threshold_db`` (noise power 1); a plot's power is signal + noise, exponential with mean
    1 + SNR (Swerling 1 fluctuation), and reported plots are those above the threshold. Exponentials are
    memoryless, so the reported power is the threshold plus an exponential excess of the same mean:

        snr_db = 10 log10(T + E),  T = 10^(threshold_db/10),  E ~ Exp(1 + 10^(mean_db/10)),

    with ``mean_db`` = ``target_mean_db`` for target echoes and ``clutter_mean_db`` for clutter plots
    (clutter echoes of that mean clutter-to-noise ratio; -inf dB would be thermal-noise false alarms).
    """

    model: Literal["fixed", "swerling1"] = "fixed"
    threshold_db: float = 13.0
    target_mean_db: float = 20.0
    clutter_mean_db: float = 10.0

    def draw(self, rng: np.random.Generator, mean_db: float, n: int) -> FloatArray:
        excess = rng.exponential(1.0 + 10.0 ** (mean_db / 10.0), n)
        return np.asarray(10.0 * np.log10(10.0 ** (self.threshold_db / 10.0) + excess), dtype=np.float64)


@dataclass(frozen=True)
class PclScenario:
    """A simulated receiver–illuminator pair, its targets, detection, clutter and noise."""

    name: str = "paper"
    tx_position_enu_m: tuple[float, float, float] = PAPER_TX_M
    receiver_id: str = "rx1"
    illuminator_id: str = "tx-fm-98.1"
    scan_period_s: float = 3.0
    n_scans: int = 51
    t0_ns: int = 0
    targets: tuple[TargetSpec, ...] = ()
    p_detection: float = 1.0
    clutter: ClutterSpec = field(default_factory=ClutterSpec)
    sigma: tuple[float, float, float, float] = PAPER_SIGMA
    include_sigmas: bool = True
    range_form: Literal["bistatic_range", "range_sum", "delay"] = "bistatic_range"
    velocity_form: Literal["velocity", "doppler"] = "velocity"
    wavelength_m: float = 3.06
    doppler_sign: int = -1
    drop_scans: tuple[int, ...] = ()  # 1-based scan numbers whose target plots are removed (E3, E4)
    snr: SnrSpec = field(default_factory=SnrSpec)

    def times_s(self) -> FloatArray:
        """Scan times on the scenario clock (s): t0 + k * period (the targets' times are on this clock too)."""
        return self.t0_ns * 1e-9 + np.arange(self.n_scans, dtype=np.float64) * self.scan_period_s

    def stamp_ns(self, k: int) -> int:
        return self.t0_ns + round(k * self.scan_period_s * 1e9)

    def tracker_config(self, **tracker: object) -> PclTrackerConfig:
        """A tracker configuration matching this scenario's geometry (tracker fields overridable)."""
        geo = GeometryConfig(
            receiver_id=self.receiver_id,
            illuminator_id=self.illuminator_id,
            tx_position_enu_m=self.tx_position_enu_m,
            wavelength_m=self.wavelength_m,
            doppler_sign=-1 if self.doppler_sign < 0 else 1,
        )
        cfg = PclTrackerConfig(geometry=geo)
        return cfg.with_tracker(**tracker) if tracker else cfg


@dataclass
class SimRun:
    """One simulated run: the input messages and the truth needed by the metrics."""

    scenario: PclScenario
    scans: list[BistaticScan]
    truth: list[list[Truth]]
    times_s: FloatArray  # (T,)
    true_states: FloatArray  # (T, n_targets, 6), NaN where a target is not alive
    plot_origin: list[dict[str, int]]  # per scan: plot_id -> target index, -1 for clutter


def paper_target() -> TargetSpec:
    """The paper's target (digest §3.1): 200 m/s on course 256 deg at 1 km altitude."""
    c = math.radians(PAPER_COURSE_DEG)
    return TargetSpec("target1", PAPER_P0_M, (PAPER_SPEED_MPS * math.sin(c), PAPER_SPEED_MPS * math.cos(c), 0.0))


def paper_scenario(**changes: object) -> PclScenario:
    """Digest §3.1: one target, P_d = 1, no clutter, 51 scans every 3 s."""
    base = PclScenario(name="paper", targets=(paper_target(),))
    return _replace(base, **changes)


def clutter_scenario(**changes: object) -> PclScenario:
    """Digest §4.4 E5: the paper target in Poisson clutter of mean 20 plots per scan."""
    base = PclScenario(name="clutter", targets=(paper_target(),), clutter=ClutterSpec(rate_per_scan=20.0))
    return _replace(base, **changes)


def many_target_scenario(n_targets: int = 20, seed: int = 7, **changes: object) -> PclScenario:
    """Many simultaneous targets (straight, or turning at 0.3-0.8 deg/s for 40 s) within 15-60 km [E].

    P_d = 0.95 and 10 clutter plots per scan. The layout comes from its own seed so it is the same in every
    Monte-Carlo run. Track it with q of about 10 m^2/s^4 (turns up to ~3.5 m/s^2).
    """
    rng = np.random.default_rng(seed)
    targets = []
    for i in range(n_targets):
        rng_km = rng.uniform(15.0, 60.0)
        bearing = rng.uniform(-math.pi, math.pi)
        p0 = (rng_km * 1000.0 * math.sin(bearing), rng_km * 1000.0 * math.cos(bearing), rng.uniform(500.0, 8000.0))
        speed = rng.uniform(120.0, 280.0)
        course = rng.uniform(-math.pi, math.pi)
        v0 = (speed * math.sin(course), speed * math.cos(course), 0.0)
        turn = float(rng.choice([0.0, 0.0, 1.0, -1.0])) * rng.uniform(0.3, 0.8)
        targets.append(TargetSpec(f"target{i + 1}", p0, v0, turn_rate_dps=turn, turn_start_s=40.0, turn_end_s=80.0))
    base = PclScenario(
        name=f"many{n_targets}",
        targets=tuple(targets),
        p_detection=0.95,
        clutter=ClutterSpec(rate_per_scan=10.0, rb_range_m=(0.0, 150_000.0)),
    )
    return _replace(base, **changes)


def _replace(s: PclScenario, **changes: object) -> PclScenario:
    from dataclasses import replace

    return replace(s, **changes)  # type: ignore[arg-type]


def true_bistatic(states: FloatArray, tx: tuple[float, float, float]) -> FloatArray:
    """Noise-free z_b = [r_b, a, e, v_b] of Cartesian states (..., 6)."""
    return h_b(states, np.asarray(tx, dtype=np.float64))


def _plot(sc: PclScenario, plot_id: str, z: FloatArray, L: float, snr_db: float | None) -> BistaticPlot:
    r_b, az, el, v_b = (float(v) for v in z)
    rng_kw: dict[str, float] = {}
    if sc.range_form == "bistatic_range":
        rng_kw["bistatic_range_m"] = r_b
    elif sc.range_form == "range_sum":
        rng_kw["range_sum_m"] = r_b + L
    else:
        rng_kw["delay_s"] = r_b / SPEED_OF_LIGHT_MPS
    if sc.velocity_form == "velocity":
        rng_kw["bistatic_velocity_mps"] = v_b
    else:
        rng_kw["doppler_hz"] = v_b / (sc.doppler_sign * sc.wavelength_m)
    if sc.include_sigmas:
        rng_kw.update(
            sigma_rb_m=sc.sigma[0], sigma_az_deg=sc.sigma[1], sigma_el_deg=sc.sigma[2], sigma_vb_mps=sc.sigma[3]
        )
    return BistaticPlot(
        plot_id=plot_id,
        azimuth_deg=float(np.degrees(wrap_pi(az))),
        elevation_deg=float(np.clip(np.degrees(el), -90.0, 90.0)),
        snr_db=snr_db,
        **rng_kw,
    )


def simulate(sc: PclScenario, rng: np.random.Generator, *, frame_id: str = "pcl_enu", source: str = "sim") -> SimRun:
    """Simulate one run of a scenario (``frame_id`` and ``source`` go into every header)."""
    tx = np.asarray(sc.tx_position_enu_m, dtype=np.float64)
    L = float(np.linalg.norm(tx))
    times = sc.times_s()
    n_t = len(sc.targets)
    states = np.full((len(times), n_t, 6), np.nan)
    sig = np.array([sc.sigma[0], math.radians(sc.sigma[1]), math.radians(sc.sigma[2]), sc.sigma[3]])
    scans: list[BistaticScan] = []
    truths: list[list[Truth]] = []
    origins: list[dict[str, int]] = []
    cl = sc.clutter
    for k, t in enumerate(times):
        stamp = sc.stamp_ns(k)
        hdr = Header(stamp_ns=stamp, frame_id=frame_id, source=source)
        zs: list[tuple[FloatArray, int, float]] = []
        tr_msgs: list[Truth] = []
        for i, tgt in enumerate(sc.targets):
            s = tgt.state(float(t))
            if s is None:
                continue
            states[k, i] = s
            tr_msgs.append(
                Truth(header=hdr, platform=tgt.target_id, position_m=s[:3].tolist(), velocity_mps=s[3:].tolist())
            )
            detected = rng.random() < sc.p_detection
            noise = rng.standard_normal(4) * sig
            if not detected or (k + 1) in sc.drop_scans:
                continue
            z = true_bistatic(s, sc.tx_position_enu_m) + noise
            snr_t = float(sc.snr.draw(rng, sc.snr.target_mean_db, 1)[0]) if sc.snr.model == "swerling1" else 20.0
            zs.append((z, i, snr_t))
        n_cl = int(rng.poisson(cl.rate_per_scan)) if cl.rate_per_scan > 0 else 0
        if n_cl:
            u = rng.random((n_cl, 4))
            lo = np.array(
                [
                    cl.rb_range_m[0],
                    math.radians(cl.az_range_deg[0]),
                    math.radians(cl.el_range_deg[0]),
                    cl.vb_range_mps[0],
                ]
            )
            hi = np.array(
                [
                    cl.rb_range_m[1],
                    math.radians(cl.az_range_deg[1]),
                    math.radians(cl.el_range_deg[1]),
                    cl.vb_range_mps[1],
                ]
            )
            snr_c = sc.snr.draw(rng, sc.snr.clutter_mean_db, n_cl) if sc.snr.model == "swerling1" else None
            for m, row in enumerate(lo + u * (hi - lo)):
                zs.append((row, -1, 13.0 if snr_c is None else float(snr_c[m])))
        order = rng.permutation(len(zs))
        plots: list[BistaticPlot] = []
        origin: dict[str, int] = {}
        for n, j in enumerate(order):
            z, who, snr = zs[int(j)]
            pid = f"p{n:04d}"
            if z[0] < -3.0 * sc.sigma[0]:
                continue  # the sensor would not report an impossible range this far below the baseline
            plots.append(_plot(sc, pid, z, L, snr))
            origin[pid] = who
        scans.append(
            BistaticScan(
                header=hdr, receiver_id=sc.receiver_id, illuminator_id=sc.illuminator_id, scan_id=k + 1, plots=plots
            )
        )
        truths.append(tr_msgs)
        origins.append(origin)
    return SimRun(sc, scans, truths, times, states, origins)


# ----- vectorised single-target noise for the Monte-Carlo experiments of digest §3.4 -------------------------


def paper_truth(times_s: FloatArray | None = None) -> FloatArray:
    """True Cartesian states (T, 6) of the paper target at the scan times (default 0, 3, ..., 150 s)."""
    t = paper_scenario().times_s() if times_s is None else np.asarray(times_s, dtype=np.float64)
    tgt = paper_target()
    return np.stack([tgt.state(float(tt)) for tt in t])  # type: ignore[misc]


def noisy_plots(
    truth_states: FloatArray,
    rng: np.random.Generator,
    n_runs: int,
    sigma: tuple[float, float, float, float] = PAPER_SIGMA,
    tx: tuple[float, float, float] = PAPER_TX_M,
) -> tuple[FloatArray, FloatArray]:
    """Noisy plots z (R, T, 4) [r_b m, a rad, e rad, v_b m/s] of a single target, and sigmas (4,) in rad units.

    Noise N(0, sigma^2) per component (digest §3.4); azimuth wrapped to (-pi, pi].
    """
    sig = np.array([sigma[0], math.radians(sigma[1]), math.radians(sigma[2]), sigma[3]])
    z_true = true_bistatic(truth_states, tx)
    z = z_true[None, :, :] + rng.standard_normal((n_runs, *z_true.shape)) * sig
    z[..., 1] = wrap_pi(z[..., 1])
    return z, sig


def scan_from_bistatic(
    scan_id: int,
    stamp_ns: int,
    z: FloatArray | list[list[float]],
    *,
    receiver_id: str = "rx1",
    illuminator_id: str = "tx-fm-98.1",
    sigma: tuple[float, float, float, float] | None = PAPER_SIGMA,
    plot_ids: list[str] | None = None,
) -> BistaticScan:
    """A scan message from rows z = [r_b m, a rad, e rad, v_b m/s] (tests, replay of array simulations)."""
    rows = np.asarray(z, dtype=np.float64).reshape(-1, 4)
    plots = []
    for i, (r_b, az, el, v_b) in enumerate(rows):
        kw: dict[str, float] = {}
        if sigma is not None:
            kw = {"sigma_rb_m": sigma[0], "sigma_az_deg": sigma[1], "sigma_el_deg": sigma[2], "sigma_vb_mps": sigma[3]}
        plots.append(
            BistaticPlot(
                plot_id=plot_ids[i] if plot_ids is not None else f"p{i:04d}",
                azimuth_deg=float(np.degrees(az)),
                elevation_deg=float(np.degrees(el)),
                bistatic_range_m=float(r_b),
                bistatic_velocity_mps=float(v_b),
                **kw,
            )
        )
    return BistaticScan(
        header=Header(stamp_ns=stamp_ns, frame_id="pcl_enu", source="sim"),
        receiver_id=receiver_id,
        illuminator_id=illuminator_id,
        scan_id=scan_id,
        plots=plots,
    )
