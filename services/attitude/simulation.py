"""Truth and measurement simulation for the attitude estimator (pure: numpy Generator in, messages out).

Truth aircraft fly coordinated (no sideslip, lift along the body normal axis) in the flat radar frame E
(x north, y up, z east). A :class:`FlightPlan` is a start state plus segments of constant-rate (or linearly
ramped) turn, flight-path-angle rate and longitudinal acceleration; the true roll follows from the specific
force (vector form of §1.6), independently of eq. (4). Measurements are the true spherical coordinates plus
independent Gaussian noise (§4.6). The paper's scenario (§3.1) is :func:`paper_plan`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.integrate import solve_ivp

from schemas import Header, Message, RadarPlot, Truth
from shared.filters import gauss_markov

from .config import MeasurementSigmas
from .geometry import F64

G_TRUTH_MPS2 = 9.81
NS = 1_000_000_000


@dataclass(frozen=True)
class Segment:
    """A manoeuvre segment: rates ramp linearly from the first to the second value over the segment.

    Either kinematic rates (``turn_rate_dps``, ``pitch_rate_dps``) or, when ``bank_deg`` or ``load_factor`` is
    given, the coordinated-flight equations of §1.6 drive the path (both ramped linearly, ``None`` = not used):

        V theta_dot = n g cos(gamma) - g cos(theta),     V psi_dot cos(theta) = n g sin(gamma)

    with ``load_factor`` n (default: the n that keeps theta constant, n = cos(theta) / cos(gamma)) and bank
    gamma (``bank_deg``, default 0). The kinematic rates are added on top. ``gravity_speed`` adds
    dV/dt = -g sin(theta) (an unpowered pull-up or zero-g parabola) to ``accel_mps2``.
    """

    duration_s: float
    turn_rate_dps: tuple[float, float] = (0.0, 0.0)  # d(psi)/dt, deg/s, + clockwise seen from above
    pitch_rate_dps: tuple[float, float] = (0.0, 0.0)  # d(theta)/dt of the flight-path angle, deg/s
    accel_mps2: float = 0.0  # dV/dt, m/s^2
    bank_deg: tuple[float, float] | None = None  # coordinated bank gamma, deg, + right wing down
    load_factor: tuple[float, float] | None = None  # normal load factor n (lift / weight)
    gravity_speed: bool = False  # dV/dt also gets -g sin(theta)


@dataclass(frozen=True)
class Wander:
    """Small random manoeuvres of a flying aircraft (light turbulence, pilot corrections): independent
    Ornstein-Uhlenbeck accelerations across the path (horizontal), normal to it (vertical) and along it, each of
    standard deviation ``sigma_*_mps2`` and correlation time ``tau_s``, sampled every ``step_s`` and interpolated
    linearly; the realisation is fixed by ``seed``. The jerk of an OU acceleration has the spectral density
    2 sigma^2 / tau, which a random-jerk model of period T matches with sigma_j^2 = 2 sigma^2 / (tau T)
    (sigma = 0.2 m/s^2, tau = 20 s, T = 5 s: sigma_j = 0.028 m/s^3, the digest's 0.03)."""

    sigma_lat_mps2: float = 0.2
    sigma_vert_mps2: float = 0.2
    sigma_long_mps2: float = 0.05
    tau_s: float = 20.0
    seed: int = 0
    step_s: float = 1.0

    def sample(self, t_end_s: float) -> tuple[F64, F64]:
        """(grid times (n,), accelerations (n, 3) = [lateral, vertical, longitudinal]) over [0, t_end_s]."""
        n = math.ceil(t_end_s / self.step_s) + 2
        t = np.arange(n, dtype=np.float64) * self.step_s
        rng = np.random.default_rng(self.seed)
        sig = np.array([self.sigma_lat_mps2, self.sigma_vert_mps2, self.sigma_long_mps2])
        phi, q1 = gauss_markov.discretise(self.step_s, self.tau_s, 1.0)  # unit variance: sig scales the draws
        e = rng.standard_normal((n, 3)) * sig * math.sqrt(q1)
        a = np.empty((n, 3))
        a[0] = rng.standard_normal(3) * sig  # stationary start
        for k in range(1, n):
            a[k] = phi * a[k - 1] + e[k]
        return t, a


@dataclass(frozen=True)
class FlightPlan:
    """Initial state and manoeuvre segments; after the last segment the aircraft flies straight."""

    p0_m: tuple[float, float, float]
    speed_mps: float
    psi_deg: float
    theta_deg: float = 0.0
    segments: tuple[Segment, ...] = ()
    wander: Wander | None = None  # small random manoeuvres on top of the segments (None: exact segments)


@dataclass(frozen=True)
class TruthStates:
    """True kinematics and attitude sampled at times ``t_s`` (shape (K,)); vectors (K, 3); angles rad."""

    t_s: F64
    p: F64
    v: F64
    a: F64
    psi: F64
    theta: F64
    gamma: F64


def paper_plan(
    r0_m: float = 100e3, az0_deg: float = 60.0, h0_m: float = 5e3, psi_deg: float = 220.0, speed_mps: float = 200.0
) -> FlightPlan:
    """The §3.1 scenario: straight and level flight from slant range r0 at azimuth az0 and altitude h0."""
    eps0 = math.asin(h0_m / r0_m)
    b = math.radians(az0_deg)
    p0 = (r0_m * math.cos(eps0) * math.cos(b), h0_m, r0_m * math.cos(eps0) * math.sin(b))
    return FlightPlan(p0_m=p0, speed_mps=speed_mps, psi_deg=psi_deg)


def scan_times(n_scans: int, scan_period_s: float = 5.0, t0_s: float = 0.0) -> F64:
    """t_k = t0 + T (k - 1), k = 1..n_scans (§4.6)."""
    return t0_s + scan_period_s * np.arange(n_scans, dtype=np.float64)


def _unit(psi: F64, theta: F64) -> tuple[F64, F64, F64]:
    """i (along the velocity), di/dpsi and di/dtheta, each (K, 3)."""
    cp, sp, ct, st = np.cos(psi), np.sin(psi), np.cos(theta), np.sin(theta)
    i = np.stack([ct * cp, st, ct * sp], axis=-1)
    di_dpsi = np.stack([-ct * sp, np.zeros_like(cp), ct * cp], axis=-1)
    di_dth = np.stack([-st * cp, ct, -st * sp], axis=-1)
    return i, di_dpsi, di_dth


def coordinated_roll(v: F64, a: F64, g: float = G_TRUTH_MPS2) -> F64:
    """True roll of coordinated flight (rad) from velocity and acceleration: the tilt of the normal specific
    force f - (f.i) i, f = a - (0, -g, 0), about the velocity, measured from the vertical plane (§1.6 vector form).
    """
    speed = np.linalg.norm(v, axis=-1)
    i = v / speed[..., None]
    f = a + np.array([0.0, g, 0.0])
    f_perp = f - np.sum(f * i, axis=-1)[..., None] * i
    psi = np.arctan2(v[..., 2], v[..., 0])
    theta = np.arctan2(v[..., 1], np.hypot(v[..., 0], v[..., 2]))
    cp, sp, ct, st = np.cos(psi), np.sin(psi), np.cos(theta), np.sin(theta)
    j0 = np.stack([-st * cp, ct, -st * sp], axis=-1)
    k0 = np.stack([-sp, np.zeros_like(sp), cp], axis=-1)
    return np.arctan2(np.sum(f_perp * k0, axis=-1), np.sum(f_perp * j0, axis=-1))


def fly(plan: FlightPlan, times_s: Sequence[float] | F64, g: float = G_TRUTH_MPS2) -> TruthStates:
    """Sample the true trajectory of a flight plan at ``times_s`` (s, ascending, >= 0)."""
    t = np.asarray(times_s, dtype=np.float64)
    psi0, th0 = math.radians(plan.psi_deg), math.radians(plan.theta_deg)
    if not plan.segments and plan.wander is None:  # straight line: closed form
        i0, _, _ = _unit(np.array([psi0]), np.array([th0]))
        v = np.repeat(i0 * plan.speed_mps, t.size, axis=0)
        p = np.asarray(plan.p0_m) + v * t[:, None]
        a = np.zeros_like(p)
        psi = np.full(t.size, psi0 % (2 * math.pi))
        return TruthStates(t, p, v, a, psi, np.full(t.size, th0), coordinated_roll(v, a, g))

    # piecewise integration of [x, y, z, V, psi, theta]
    bounds = [0.0]
    for seg in plan.segments:
        bounds.append(bounds[-1] + seg.duration_s)
    t_end = max(float(t.max()), bounds[-1]) + 1.0
    segs = [*plan.segments, Segment(duration_s=t_end - bounds[-1])]
    bounds.append(t_end)
    grid_step, wander_acc = 1.0, np.zeros((2, 3))
    if plan.wander is not None:
        grid_step = plan.wander.step_s
        wander_acc = plan.wander.sample(t_end)[1]
    wander_on = plan.wander is not None

    def forcing(tt: float) -> tuple[float, float, float]:
        """The wander's (lateral, vertical, longitudinal) acceleration at tt, linear between grid samples."""
        u = tt / grid_step
        i = min(max(int(u), 0), wander_acc.shape[0] - 2)
        f = u - i
        lo, hi = wander_acc[i], wander_acc[i + 1]
        return (
            float(lo[0] + f * (hi[0] - lo[0])),
            float(lo[1] + f * (hi[1] - lo[1])),
            float(lo[2] + f * (hi[2] - lo[2])),
        )

    def rates(k: int, tt: float, speed: float, theta: float) -> tuple[float, float, float]:
        """(d psi/dt, d theta/dt, dV/dt) of segment k at time tt, speed (m/s) and flight-path angle (rad)."""
        seg = segs[k]
        f = (tt - bounds[k]) / seg.duration_s
        w = math.radians(seg.turn_rate_dps[0] + f * (seg.turn_rate_dps[1] - seg.turn_rate_dps[0]))
        q = math.radians(seg.pitch_rate_dps[0] + f * (seg.pitch_rate_dps[1] - seg.pitch_rate_dps[0]))
        vdot = seg.accel_mps2 - (g * math.sin(theta) if seg.gravity_speed else 0.0)
        ct = math.cos(theta)
        if seg.bank_deg is not None or seg.load_factor is not None:
            bank = 0.0
            if seg.bank_deg is not None:
                bank = math.radians(seg.bank_deg[0] + f * (seg.bank_deg[1] - seg.bank_deg[0]))
            if seg.load_factor is not None:
                n = seg.load_factor[0] + f * (seg.load_factor[1] - seg.load_factor[0])
            else:
                n = ct / math.cos(bank)
            w += n * g * math.sin(bank) / (speed * ct)
            q += (n * g * math.cos(bank) - g * ct) / speed
        if wander_on:
            lat, vert, lon = forcing(tt)
            w += lat / (speed * ct)
            q += vert / speed
            vdot += lon
        return w, q, vdot

    def deriv(k: int, tt: float, s: Sequence[float]) -> list[float]:
        w, q, vdot = rates(k, tt, s[3], s[5])
        ct = math.cos(s[5])
        return [s[3] * ct * math.cos(s[4]), s[3] * math.sin(s[5]), s[3] * ct * math.sin(s[4]), vdot, w, q]

    y = np.array([*plan.p0_m, plan.speed_mps, psi0, th0], dtype=np.float64)
    out = np.empty((t.size, 6))
    seg_of = np.clip(np.searchsorted(bounds, t, side="right") - 1, 0, len(segs) - 1)
    for k in range(len(segs)):
        mask = seg_of == k
        seg_deriv = functools.partial(deriv, k)
        if wander_on:  # piecewise-linear forcing: fixed-step RK4 landing on the sample times
            y = _rk4(seg_deriv, bounds[k], bounds[k + 1], y, t[mask], out, np.flatnonzero(mask))
            continue
        sol = solve_ivp(
            seg_deriv,
            (bounds[k], bounds[k + 1]),
            y,
            method="DOP853",
            rtol=1e-11,
            atol=1e-9,
            dense_output=True,
        )
        if mask.any():
            assert sol.sol is not None
            out[mask] = sol.sol(t[mask]).T
        y = sol.y[:, -1]
    p = out[:, 0:3]
    speed, psi, theta = out[:, 3], out[:, 4], out[:, 5]
    i, di_dpsi, di_dth = _unit(psi, theta)
    w = np.empty(t.size)
    q = np.empty(t.size)
    acc = np.empty(t.size)
    for n_, (k, tt) in enumerate(zip(seg_of.tolist(), t.tolist(), strict=True)):
        w[n_], q[n_], acc[n_] = rates(k, tt, float(speed[n_]), float(theta[n_]))
    v = speed[:, None] * i
    a = acc[:, None] * i + speed[:, None] * (w[:, None] * di_dpsi + q[:, None] * di_dth)
    return TruthStates(t, p, v, a, np.mod(psi, 2 * math.pi), theta, coordinated_roll(v, a, g))


#: step of the fixed-step integration of a wandering flight, s (a quarter of the wander's grid step at most)
RK4_STEP_S = 0.25


def _rk4(
    deriv: Callable[[float, list[float]], list[float]],
    t0: float,
    t1: float,
    y: F64,
    samples_s: F64,
    out: F64,
    rows: npt.NDArray[np.intp],
) -> F64:
    """Classic 4th-order Runge-Kutta from t0 to t1 with steps of at most RK4_STEP_S that land on every sample
    time (the forcing is smooth between the steps' ends); writes the state at samples_s into out[rows] and
    returns the state at t1."""
    stops = np.unique(np.concatenate([np.linspace(t0, t1, max(2, math.ceil((t1 - t0) / RK4_STEP_S) + 1)), samples_s]))
    want = dict(zip(samples_s.tolist(), rows.tolist(), strict=True))
    ys = np.asarray(y, dtype=np.float64).tolist()
    t_prev = float(stops[0])
    if t_prev in want:
        out[want[t_prev]] = ys
    for t_next in stops[1:].tolist():
        h = t_next - t_prev
        k1 = deriv(t_prev, ys)
        k2 = deriv(t_prev + 0.5 * h, [a + 0.5 * h * b for a, b in zip(ys, k1, strict=True)])
        k3 = deriv(t_prev + 0.5 * h, [a + 0.5 * h * b for a, b in zip(ys, k2, strict=True)])
        k4 = deriv(t_next, [a + h * b for a, b in zip(ys, k3, strict=True)])
        ys = [a + h / 6.0 * (b + 2.0 * c + 2.0 * d + e) for a, b, c, d, e in zip(ys, k1, k2, k3, k4, strict=True)]
        t_prev = t_next
        if t_prev in want:
            out[want[t_prev]] = ys
    return np.asarray(ys, dtype=np.float64)


def true_spherical(p: F64) -> tuple[F64, F64, F64]:
    """True (range m, azimuth rad in [0, 2 pi), elevation rad) of positions (..., 3)."""
    r = np.linalg.norm(p, axis=-1)
    beta = np.mod(np.arctan2(p[..., 2], p[..., 0]), 2 * math.pi)
    eps = np.arcsin(p[..., 1] / r)
    return r, beta, eps


def measure(truth: TruthStates, sigmas: MeasurementSigmas, rng: np.random.Generator, n_runs: int = 1) -> F64:
    """Noisy plots (n_runs, K, 3) = [range m, azimuth deg in [0, 360), elevation deg]: truth + N(0, sigma^2).

    The noise is drawn as one standard-normal block, scan-major (K, n_runs, 3), scaled by the sigmas: two calls
    with equal seeds and run counts use common random numbers for any sigmas, trajectories and (leading) scans.
    """
    r, beta, eps = true_spherical(truth.p)
    z = rng.standard_normal((truth.t_s.size, n_runs, 3)).transpose(1, 0, 2)
    out = np.empty_like(z)
    out[..., 0] = r + sigmas.sigma_r_m * z[..., 0]
    out[..., 1] = np.mod(np.degrees(beta) + sigmas.sigma_az_deg * z[..., 1], 360.0)
    out[..., 2] = np.degrees(eps) + sigmas.sigma_el_deg * z[..., 2]
    return out


def plot_messages(
    site_id: str, target_id: str, stamps_ns: Sequence[int], meas: F64, frame_id: str = "", source: str = "sim"
) -> list[RadarPlot]:
    """RadarPlot messages of one target from measurements (K, 3) [range m, az deg, el deg]."""
    rows = meas.tolist()
    return [
        RadarPlot(
            header=Header(stamp_ns=int(s), frame_id=frame_id, source=source, seq=k),
            site_id=site_id,
            target_id=target_id,
            range_m=row[0],
            az_deg=row[1],
            el_deg=row[2],
        )
        for k, (s, row) in enumerate(zip(stamps_ns, rows, strict=True))
    ]


def truth_messages(
    platform: str, truth: TruthStates, stamps_ns: Sequence[int], frame_id: str = "", source: str = "sim"
) -> list[Truth]:
    """Truth messages (position, velocity, acceleration, attitude [heading, pitch, roll] rad) in frame E."""
    return [
        Truth(
            header=Header(stamp_ns=int(s), frame_id=frame_id, source=source, seq=k),
            platform=platform,
            position_m=truth.p[k].tolist(),
            velocity_mps=truth.v[k].tolist(),
            acceleration_mps2=truth.a[k].tolist(),
            attitude_rad=[float(truth.psi[k]), float(truth.theta[k]), float(truth.gamma[k])],
        )
        for k, s in enumerate(stamps_ns)
    ]


@dataclass(frozen=True)
class Scenario:
    """Several targets seen by one radar site; ``phase_s`` offsets a target's plot times within the scan."""

    site_id: str
    targets: dict[str, FlightPlan]
    sigmas: MeasurementSigmas
    n_scans: int = 100
    scan_period_s: float = 5.0
    t0_ns: int = 0
    phase_s: dict[str, float] = field(default_factory=dict)


def scenario_truth(scenario: Scenario) -> dict[str, tuple[list[int], TruthStates]]:
    """Plot stamps (ns) and truth of every target."""
    out: dict[str, tuple[list[int], TruthStates]] = {}
    for tid, plan in scenario.targets.items():
        t = scan_times(scenario.n_scans, scenario.scan_period_s, scenario.phase_s.get(tid, 0.0))
        out[tid] = ([scenario.t0_ns + round(x * NS) for x in t], fly(plan, t))
    return out


def scenario_messages(scenario: Scenario, rng: np.random.Generator, frame_id: str = "") -> list[Message]:
    """Every RadarPlot and Truth message of a scenario, ordered by stamp (a truth before the plot it matches)."""
    frame = frame_id or f"radar_nue/{scenario.site_id}"
    msgs: list[tuple[int, int, str, Message]] = []
    for tid, (stamps, truth) in scenario_truth(scenario).items():
        meas = measure(truth, scenario.sigmas, rng)[0]
        msgs.extend((t.header.stamp_ns, 0, tid, t) for t in truth_messages(tid, truth, stamps, frame))
        msgs.extend((p.header.stamp_ns, 1, tid, p) for p in plot_messages(scenario.site_id, tid, stamps, meas, frame))
    msgs.sort(key=lambda e: (e[0], e[1], e[2]))
    return [m for *_, m in msgs]


def manoeuvring_plans() -> dict[str, FlightPlan]:
    """Three manoeuvring targets for the multi-target scenario (true attitude known at every plot).

    * ``turn30``: level, 200 m/s, enters a 30 deg coordinated right turn (rate g tan 30 / V) for 90 s;
    * ``climb10``: pulls up to a 10 deg climb at 0.5 deg/s, climbs 60 s, pushes over to level at -0.5 deg/s;
    * ``weave``: left 20 deg-bank turn then right 20 deg-bank turn, 45 s each, at 250 m/s.
    """
    v1, v3 = 200.0, 250.0
    w30 = math.degrees(G_TRUTH_MPS2 * math.tan(math.radians(30.0)) / v1)
    w20 = math.degrees(G_TRUTH_MPS2 * math.tan(math.radians(20.0)) / v3)
    return {
        "turn30": FlightPlan(
            p0_m=(40e3, 6e3, 30e3),
            speed_mps=v1,
            psi_deg=200.0,
            segments=(Segment(150.0), Segment(3.0, (0.0, w30)), Segment(90.0, (w30, w30)), Segment(3.0, (w30, 0.0))),
        ),
        "climb10": FlightPlan(
            p0_m=(-30e3, 3e3, 45e3),
            speed_mps=v1,
            psi_deg=120.0,
            segments=(
                Segment(150.0),
                Segment(20.0, pitch_rate_dps=(0.5, 0.5)),
                Segment(60.0),
                Segment(20.0, pitch_rate_dps=(-0.5, -0.5)),
            ),
        ),
        "weave": FlightPlan(
            p0_m=(50e3, 8e3, -40e3),
            speed_mps=v3,
            psi_deg=300.0,
            segments=(
                Segment(150.0),
                Segment(3.0, (0.0, -w20)),
                Segment(45.0, (-w20, -w20)),
                Segment(6.0, (-w20, w20)),
                Segment(45.0, (w20, w20)),
                Segment(3.0, (w20, 0.0)),
            ),
        ),
    }
