"""The orientation-angle block (§1.6, §2.5): eqs. (4) and (5), the Euler roll relative to the LOS and the aspect
angles of the radar in body axes, vectorised over a batch of 9-state vectors, with linearised sigmas.

Angle order of every array returned here (radians), see :data:`ANGLES`:
``psi, theta, gamma, psi_los, theta_los, gamma_los (paper form), gamma_los_euler, aspect_az, aspect_el,
aspect_total``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from shared.filters.angles import TWO_PI, wrap_pi_shifted

from .geometry import F64

ANGLES: tuple[str, ...] = (
    "psi",
    "theta",
    "gamma",
    "psi_los",
    "theta_los",
    "gamma_los",
    "gamma_los_euler",
    "aspect_az",
    "aspect_el",
    "aspect_total",
)
IDX: dict[str, int] = {name: i for i, name in enumerate(ANGLES)}
N_ANGLES = len(ANGLES)


@dataclass(frozen=True)
class AngleConventions:
    """Conventions of the angle block (§5.2): gravity (m/s^2), LOS x direction and roll form of eq. (4)."""

    g_mps2: float = 9.81
    los_x: Literal["radar_to_target", "target_to_radar"] = "radar_to_target"
    roll_mode: Literal["arctan", "atan2"] = "arctan"


@dataclass(frozen=True)
class EarthKinematics:
    """Eq. (4) and its by-products for a batch of states; every field has shape (m,)."""

    psi: F64  # heading, rad in [0, 2 pi)
    theta: F64  # pitch (flight-path angle), rad
    gamma: F64  # roll, rad; (-pi/2, pi/2) in arctan mode
    psi_dot: F64  # rad/s
    theta_dot: F64  # rad/s
    speed: F64  # V, m/s
    v_h: F64  # horizontal speed, m/s
    load_factor: F64  # normal load factor n (signed in arctan mode), dimensionless


def earth_kinematics(v: F64, a: F64, conv: AngleConventions) -> EarthKinematics:
    """Eq. (4): heading, pitch and roll from velocity v (m/s) and acceleration a (m/s^2), shapes (m, 3).

    Undefined quantities (V_h = 0) come out as NaN.
    """
    return _earth(v[:, 0], v[:, 1], v[:, 2], a[:, 0], a[:, 1], a[:, 2], conv)[0]


def _earth(
    vx: F64, vy: F64, vz: F64, ax: F64, ay: F64, az: F64, conv: AngleConventions
) -> tuple[EarthKinematics, tuple[F64, F64, F64, F64]]:
    """Eq. (4) on component arrays; also returns (cos psi, sin psi, cos theta, sin theta)."""
    vh2 = vx * vx + vz * vz
    v2 = vh2 + vy * vy
    vh = np.sqrt(vh2)
    speed = np.sqrt(v2)
    with np.errstate(divide="ignore", invalid="ignore"):
        psi = np.arctan2(vz, vx)
        psi = np.where(psi < 0.0, psi + TWO_PI, psi)
        psi = np.where(psi >= TWO_PI, 0.0, psi)
        psi = np.where(vh > 0.0, psi, np.nan)
        theta = np.arctan2(vy, vh)
        psi_dot = (az * vx - ax * vz) / vh2
        theta_dot = (ay * vh2 - vy * (ax * vx + az * vz)) / (vh * v2)
        cp = vx / vh
        sp = vz / vh
        ct = vh / speed
        st = vy / speed
        num = psi_dot * ct
        den = theta_dot + (conv.g_mps2 / speed) * ct
        mag = np.hypot(num, den) * (speed / conv.g_mps2)
        if conv.roll_mode == "arctan":
            gamma = np.arctan(num / den)
            load = np.where(den < 0.0, -mag, mag)
        else:
            gamma = np.arctan2(num, den)
            load = mag
    return EarthKinematics(psi, theta, gamma, psi_dot, theta_dot, speed, vh, load), (cp, sp, ct, st)


def _los_block(
    cp: F64, sp: F64, ct: F64, st: F64, cg: F64, sg: F64, cb: F64, sb: F64, ce: F64, se: F64, los_x: str
) -> tuple[F64, F64, F64, F64, F64, F64, F64]:
    """Eq. (5), the Euler roll relative to L and the aspect angles, from cosines and sines (arrays)."""
    # body axes in E (§1.2)
    ix, iy, iz = ct * cp, st, ct * sp
    cgst = cg * st
    sgst = sg * st
    jx = -cgst * cp - sg * sp
    jy = cg * ct
    jz = sg * cp - cgst * sp
    kx = sgst * cp - cg * sp
    ky = -sg * ct
    kz = sgst * sp + cg * cp
    # rows of A_LE (radar_to_target): r1 = (ce cb, se, ce sb), r2 = (-se cb, ce, -se sb), r3 = (-sb, 0, cb)
    cecb, cesb, secb, sesb = ce * cb, ce * sb, se * cb, se * sb
    ilx = cecb * ix + se * iy + cesb * iz
    ily = ce * iy - secb * ix - sesb * iz
    ilz = cb * iz - sb * ix
    jlx = cecb * jx + se * jy + cesb * jz
    jly = ce * jy - secb * jx - sesb * jz
    jlz = cb * jz - sb * jx
    klx = cecb * kx + se * ky + cesb * kz
    kly = ce * ky - secb * kx - sesb * kz
    if los_x == "radar_to_target":
        psi_los = np.arctan2(ilz, ilx)
        gamma_los = np.arctan2(jlz, jly)
    elif los_x == "target_to_radar":  # A_LE left-multiplied by diag(-1, 1, -1)
        psi_los = np.arctan2(-ilz, -ilx)
        gamma_los = np.arctan2(-jlz, jly)
    else:
        raise ValueError(f"unknown los_x {los_x!r}")
    theta_los = np.arctan2(ily, np.hypot(ilx, ilz))
    gamma_los_euler = np.arctan2(-kly, jly)
    # the radar seen from the body: u^E = -r1, u^B = (u.i, u.j, u.k) = -(ilx, jlx, klx)
    q_az = np.arctan2(-klx, -ilx)
    q_el = np.arctan2(-jlx, np.hypot(ilx, klx))
    q = np.arccos(np.clip(-ilx, -1.0, 1.0))
    return psi_los, theta_los, gamma_los, gamma_los_euler, q_az, q_el, q


def los_direction(p: F64) -> tuple[F64, F64]:
    """beta, eps (rad) of positions p (m), shape (m, 3): the LOS direction from the radar (§1.6 [CHOICE])."""
    beta = np.arctan2(p[:, 2], p[:, 0])
    eps = np.arctan2(p[:, 1], np.hypot(p[:, 0], p[:, 2]))
    return beta, eps


def attitude_angles(
    psi: F64 | float,
    theta: F64 | float,
    gamma: F64 | float,
    beta: F64 | float,
    eps: F64 | float,
    los_x: str = "radar_to_target",
) -> tuple[F64, F64, F64, F64, F64, F64, F64]:
    """Eq. (5) and the derived angles from an attitude (psi, theta, gamma) and a LOS direction (beta, eps), rad.

    Returns (psi_los, theta_los, gamma_los paper form, gamma_los_euler, aspect_az, aspect_el, aspect_total).
    """
    c = [np.cos(np.asarray(v, dtype=np.float64)) for v in (psi, theta, gamma, beta, eps)]
    s = [np.sin(np.asarray(v, dtype=np.float64)) for v in (psi, theta, gamma, beta, eps)]
    return _los_block(c[0], s[0], c[1], s[1], c[2], s[2], c[3], s[3], c[4], s[4], los_x)


def angles_of_states(
    states: F64, conv: AngleConventions, los_dir: tuple[float, float] | None = None
) -> tuple[F64, EarthKinematics]:
    """All angles (rad, shape (m, N_ANGLES)) of a batch of 9-states (m, 9), and the eq. (4) kinematics.

    ``los_dir`` = (beta, eps) fixes the LOS direction (the "measured" option); None takes it from each state's
    position (the "filtered" default). Angles that are undefined (V_h = 0) are NaN.
    """
    x = np.atleast_2d(states)
    kin, (cp, sp, ct, st) = _earth(x[:, 1], x[:, 4], x[:, 7], x[:, 2], x[:, 5], x[:, 8], conv)
    if los_dir is None:
        px, py, pz = x[:, 0], x[:, 3], x[:, 6]
        hxz = np.hypot(px, pz)
        r = np.hypot(hxz, py)
        cb, sb, ce, se = px / hxz, pz / hxz, hxz / r, py / r
    else:
        cb, sb = np.full(x.shape[0], math.cos(los_dir[0])), np.full(x.shape[0], math.sin(los_dir[0]))
        ce, se = np.full(x.shape[0], math.cos(los_dir[1])), np.full(x.shape[0], math.sin(los_dir[1]))
    with np.errstate(invalid="ignore"):
        los = _los_block(cp, sp, ct, st, np.cos(kin.gamma), np.sin(kin.gamma), cb, sb, ce, se, conv.los_x)
    out = np.empty((x.shape[0], N_ANGLES))
    out[:, 0] = kin.psi
    out[:, 1] = kin.theta
    out[:, 2] = kin.gamma
    for n, col in enumerate(los):
        out[:, 3 + n] = col
    return out, kin


def angle_jacobian(
    x: F64,
    conv: AngleConventions,
    steps: tuple[float, float, float] = (1.0, 0.1, 0.01),
    los_dir: tuple[float, float] | None = None,
    extra: F64 | None = None,
) -> tuple[F64, F64, F64 | None, EarthKinematics]:
    """Angles at x and their Jacobian J = d(angles)/d(alpha) by central differences (§2.5).

    Steps are per state kind: position (m), velocity (m/s), acceleration (m/s^2); angle differences are wrapped
    into (-pi, pi] before dividing. ``extra`` states (k, 9) are evaluated in the same batch (e.g. the raw
    baseline). Returns (angles at x (N_ANGLES,), J (N_ANGLES, 9), angles of the extra states (k, N_ANGLES) or
    None, eq. (4) kinematics of the whole batch: index 0 is x, indices 19.. are the extra states).
    """
    n_extra = 0 if extra is None else extra.shape[0]
    h = np.tile(np.asarray(steps, dtype=np.float64), 3)  # [p, v, a] per axis in axis-blocked order
    batch = np.empty((19 + n_extra, 9))
    batch[:19] = x
    idx = np.arange(9)
    batch[1 + idx, idx] += h
    batch[10 + idx, idx] -= h
    if extra is not None:
        batch[19:] = extra
    vals, kin = angles_of_states(batch, conv, los_dir)
    diff = wrap_pi_shifted(vals[1:10] - vals[10:19])  # (9, N_ANGLES)
    jac = (diff / (2.0 * h)[:, None]).T
    return vals[0], jac, (vals[19:] if extra is not None else None), kin


def deg(a: float) -> float:
    """Radians to degrees for scalars (NaN passes through)."""
    return a * 180.0 / math.pi


@dataclass(frozen=True)
class Kinematics:
    """Eq. (4) by-products of one state (scalars): rad/s, m/s, dimensionless."""

    psi_dot: float
    theta_dot: float
    speed: float
    v_h: float
    load_factor: float


_NAN10 = [math.nan] * N_ANGLES


def angle_block(
    x: list[float], conv: AngleConventions, los_dir: tuple[float, float] | None = None, jacobian: bool = True
) -> tuple[list[float], F64 | None, Kinematics]:
    """The angle block of §2.5 for one 9-state, in scalar arithmetic, with an analytic Jacobian.

    Same angles as :func:`angles_of_states` (rad, order :data:`ANGLES`). The Jacobian J = d(angles)/d(alpha)
    (N_ANGLES x 9) is exact (chain rule through psi, theta, gamma of eq. (4) and the LOS direction beta, eps);
    the tests check it against central differences with the digest's steps. Undefined angles are NaN.
    """
    px, vx, ax, py, vy, ay, pz, vz, az = x
    g = conv.g_mps2
    vh2 = vx * vx + vz * vz
    v2 = vh2 + vy * vy
    vh = math.sqrt(vh2)
    speed = math.sqrt(v2)
    if vh == 0.0:
        theta0 = math.atan2(vy, vh) if speed > 0.0 else math.nan
        vals = list(_NAN10)
        vals[1] = theta0
        return vals, None, Kinematics(math.nan, math.nan, speed, vh, math.nan)
    psi = math.atan2(vz, vx)
    if psi < 0.0:
        psi += TWO_PI
        if psi >= TWO_PI:  # -tiny + 2 pi rounds to 2 pi: keep [0, 2 pi)
            psi = 0.0
    theta = math.atan2(vy, vh)
    cp, sp, ct, st = vx / vh, vz / vh, vh / speed, vy / speed
    a_h = ax * vx + az * vz
    c_h = az * vx - ax * vz
    psi_dot = c_h / vh2
    theta_dot = (ay * vh2 - vy * a_h) / (vh * v2)
    # eq. (4): tan(gamma) = psi_dot cos(theta) / (theta_dot + g cos(theta) / V) = N / D (common factor vh V^2 > 0)
    n_ = c_h * speed
    d_ = vh2 * (ay + g) - vy * a_h
    hyp = math.hypot(n_, d_)
    load = hyp / (vh * speed * g)
    if conv.roll_mode == "arctan":
        gamma = math.atan(n_ / d_) if d_ != 0.0 else math.copysign(0.5 * math.pi, n_)
        if d_ < 0.0:
            load = -load
    else:
        gamma = math.atan2(n_, d_)
    cg, sg = math.cos(gamma), math.sin(gamma)
    # body axes in E (§1.2)
    ix, iy, iz = ct * cp, st, ct * sp
    jx = -cg * st * cp - sg * sp
    jy = cg * ct
    jz = sg * cp - cg * st * sp
    kx = sg * st * cp - cg * sp
    ky = -sg * ct
    kz = sg * st * sp + cg * cp
    # LOS direction and A_LE rows (radar_to_target; the flip is applied to the angles)
    if los_dir is None:
        hxz = math.hypot(px, pz)
        rng = math.hypot(hxz, py)
        if hxz == 0.0:
            vals = list(_NAN10)
            vals[0:3] = [psi, theta, gamma]
            return vals, None, Kinematics(psi_dot, theta_dot, speed, vh, load)
        cb, sb, ce, se = px / hxz, pz / hxz, hxz / rng, py / rng
    else:
        hxz = rng = math.nan
        cb, sb = math.cos(los_dir[0]), math.sin(los_dir[0])
        ce, se = math.cos(los_dir[1]), math.sin(los_dir[1])
    cecb, cesb, secb, sesb = ce * cb, ce * sb, se * cb, se * sb
    i1 = cecb * ix + se * iy + cesb * iz
    i2 = ce * iy - secb * ix - sesb * iz
    i3 = cb * iz - sb * ix
    j1 = cecb * jx + se * jy + cesb * jz
    j2 = ce * jy - secb * jx - sesb * jz
    j3 = cb * jz - sb * jx
    k1 = cecb * kx + se * ky + cesb * kz
    k2 = ce * ky - secb * kx - sesb * kz
    k3 = cb * kz - sb * kx
    flip = conv.los_x == "target_to_radar"
    h_i = math.hypot(i1, i3)
    h_q = math.hypot(i1, k1)
    vals = [
        psi,
        theta,
        gamma,
        math.atan2(-i3, -i1) if flip else math.atan2(i3, i1),
        math.atan2(i2, h_i),
        math.atan2(-j3, j2) if flip else math.atan2(j3, j2),
        math.atan2(-k2, j2),
        math.atan2(-k1, -i1),
        math.atan2(-j1, h_q),
        math.acos(min(1.0, max(-1.0, -i1))),
    ]
    kin = Kinematics(psi_dot, theta_dot, speed, vh, load)
    if not jacobian:
        return vals, None, kin

    # d(LOS-frame body axes)/d(psi, theta, gamma, beta, eps): rotation generators (see docs/attitude.md)
    derivs = (
        (  # psi
            (ct * (sg * j1 + cg * k1), ct * (sg * j2 + cg * k2), ct * (sg * j3 + cg * k3)),
            (-sg * ct * i1 - st * k1, -sg * ct * i2 - st * k2, -sg * ct * i3 - st * k3),
            (-cg * ct * i1 + st * j1, -cg * ct * i2 + st * j2),
        ),
        (  # theta
            (cg * j1 - sg * k1, cg * j2 - sg * k2, cg * j3 - sg * k3),
            (-cg * i1, -cg * i2, -cg * i3),
            (sg * i1, sg * i2),
        ),
        ((0.0, 0.0, 0.0), (k1, k2, k3), (-j1, -j2)),  # gamma
        (  # beta
            (ce * i3, -se * i3, se * i2 - ce * i1),
            (ce * j3, -se * j3, se * j2 - ce * j1),
            (ce * k3, -se * k3),
        ),
        ((i2, -i1, 0.0), (j2, -j1, 0.0), (k2, -k1)),  # eps
    )
    n_i = i1 * i1 + i3 * i3
    n_g = j2 * j2 + j3 * j3
    n_e = j2 * j2 + k2 * k2
    n_a = i1 * i1 + k1 * k1
    s_q = math.sqrt(max(1.0 - i1 * i1, 1e-300))
    sgn = -1.0 if flip else 1.0
    g1 = np.zeros((N_ANGLES, 5))
    g1[0, 0] = g1[1, 1] = g1[2, 2] = 1.0
    for q, ((di1, di2, di3), (dj1, dj2, dj3), (dk1, dk2)) in enumerate(derivs):
        dh_i = (i1 * di1 + i3 * di3) / h_i
        dh_q = (i1 * di1 + k1 * dk1) / h_q
        g1[3, q] = (i1 * di3 - i3 * di1) / n_i
        g1[4, q] = h_i * di2 - i2 * dh_i
        g1[5, q] = sgn * (j2 * dj3 - j3 * dj2) / n_g
        g1[6, q] = (k2 * dj2 - j2 * dk2) / n_e
        g1[7, q] = (i1 * dk1 - k1 * di1) / n_a
        g1[8, q] = -h_q * dj1 + j1 * dh_q
        g1[9, q] = di1 / s_q
    # d(psi, theta, gamma, beta, eps)/d(alpha), alpha = [x Vx ax y Vy ay z Vz az]
    g2 = np.zeros((5, 9))
    g2[0, 1] = -vz / vh2
    g2[0, 7] = vx / vh2
    g2[1, 4] = vh / v2
    g2[1, 1] = -vy * vx / (vh * v2)
    g2[1, 7] = -vy * vz / (vh * v2)
    w = 1.0 / (hyp * hyp) if hyp > 0.0 else math.nan
    dn = (speed * az + c_h * vx / speed, c_h * vy / speed, -speed * ax + c_h * vz / speed, -speed * vz, speed * vx)
    ag = ay + g
    dd = (2.0 * vx * ag - vy * ax, -a_h, 2.0 * vz * ag - vy * az, -vy * vx, vh2, -vy * vz)
    g2[2, 1] = w * (d_ * dn[0] - n_ * dd[0])
    g2[2, 4] = w * (d_ * dn[1] - n_ * dd[1])
    g2[2, 7] = w * (d_ * dn[2] - n_ * dd[2])
    g2[2, 2] = w * (d_ * dn[3] - n_ * dd[3])
    g2[2, 5] = w * (-n_ * dd[4])
    g2[2, 8] = w * (d_ * dn[4] - n_ * dd[5])
    if los_dir is None:
        r2 = rng * rng
        g2[3, 0] = -pz / (hxz * hxz)
        g2[3, 6] = px / (hxz * hxz)
        g2[4, 3] = hxz / r2
        g2[4, 0] = -py * px / (hxz * r2)
        g2[4, 6] = -py * pz / (hxz * r2)
    return vals, g1 @ g2, kin
