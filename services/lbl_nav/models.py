"""Motion and measurement models of digest 000: Eq. (1), Eq. (2), the backward step (U6) and their matrices.

State (section 1.5): X = [x, y, dc, dK, dU_N, dU_E] (m, m, m/s, rad, m/s, m/s), x = East, y = North.
Augmented state (5): [x_s, y_s, dK_s, dU_N_s, dU_E_s, X_i] (11 states); dc appears once (index 7).
dK is the correction to add to the measured heading (true heading = K~ + dK).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from shared.filters import gauss_markov

from .config import LblNavConfig

F64 = NDArray[np.float64]

# 6-state indices
IX, IY, IDC, IDK, IUN, IUE = 0, 1, 2, 3, 4, 5
# 5-state (buffered copy) indices
SX, SY, SDK, SUN, SUE = 0, 1, 2, 3, 4
#: offset of the X_i block inside the 11-state augmented vector
AUG = 5
#: the rows of X copied into the buffered block by J = [S; I_6]
COPY_IDX = (IX, IY, IDK, IUN, IUE)


@dataclass(frozen=True)
class ErrorModel:
    """The digest's error model (section 1): standard deviations (m, m/s, rad) and correlation times (s) of the
    initial position, the speed-log white noise, the sound-speed bias, the log scale error, the heading error and
    the current. The filter's configuration, the exact evidence (:class:`.evidence.Priors`) and the bounds of the
    tests (:class:`.bounds.NoiseModel`) all extend this one list."""

    sigma_delta_m: float
    sigma_v_m: float
    sigma_dc_mps: float
    sigma_dV_mps: float  # noqa: N815
    sigma_dK_rad: float  # noqa: N815
    sigma_dU_mps: float  # noqa: N815
    tau_dK_s: float  # noqa: N815
    tau_dU_s: float  # noqa: N815


@dataclass(frozen=True)
class DrIncrement:
    """Dead reckoning integrated over one interval (t_{k-1}, t_k] (section 1.5, [IMPL] sub-steps).

    ``ve_dt_m`` = integral of V^E dt and ``vn_dt_m`` = integral of V^N dt with V from the log and the measured
    heading; ``ue_dt_m``/``un_dt_m`` the same for the known current U. ``sigma_w_scale`` inflates sigma_w over
    DR gaps.
    """

    dt_s: float
    ve_dt_m: float
    vn_dt_m: float
    ue_dt_m: float = 0.0
    un_dt_m: float = 0.0
    sigma_w_scale: float = 1.0


@dataclass(frozen=True)
class DrInterval(DrIncrement):
    """A :class:`DrIncrement` as the filter sees it: ``valid`` is False when no usable DR exists for the interval
    (gap longer than the hold limit), ``gap_s`` the gap it bridged."""

    valid: bool = True
    gap_s: float = 0.0


class MotionModel:
    """Forward (2) and backward (U6) transition matrices for one DR interval."""

    def __init__(self, cfg: LblNavConfig) -> None:
        self.cfg = cfg
        self._cache: dict[float, tuple[float, float, float, float, float]] = {}

    def _coeffs(self, dt: float) -> tuple[float, float, float, float, float]:
        c = self._cache.get(dt)
        if c is None:
            cfg = self.cfg
            aK, qK = gauss_markov.discretise(dt, cfg.tau_dK_s, cfg.sigma_dK_rad, cfg.markov_form)
            aU, qU = gauss_markov.discretise(dt, cfg.tau_dU_s, cfg.sigma_dU_mps, cfg.markov_form)
            # [R] sigma_w = sigma_dV * sqrt(dt * 1 s); the printed form sigma_dV * dt is the same at dt = 1 s
            w2 = cfg.sigma_dV_mps**2 * (dt if cfg.sigma_w_form == "sqrt" else dt * dt)
            c = (aK, qK, aU, qU, w2)
            self._cache[dt] = c
        return c

    def sigma_w2(self, dr: DrInterval) -> float:
        return self._coeffs(dr.dt_s)[4] * dr.sigma_w_scale**2

    def _rotated(self, dr: DrInterval, dK_lin: float) -> tuple[float, float, float, float]:
        """[IMPL] Integrated log velocity rotated by the linearisation heading correction dK_lin and the
        displacement at dK = 0 of the model linearised there: (ve', vn', bx, by)."""
        if dK_lin == 0.0:
            return dr.ve_dt_m, dr.vn_dt_m, dr.ve_dt_m, dr.vn_dt_m
        c, s = math.cos(dK_lin), math.sin(dK_lin)
        ve = dr.ve_dt_m * c + dr.vn_dt_m * s
        vn = dr.vn_dt_m * c - dr.ve_dt_m * s
        return ve, vn, ve - vn * dK_lin, vn + ve * dK_lin

    def forward(self, dr: DrInterval, dK_prev: float = 0.0) -> tuple[F64, F64, F64]:
        """Phi_i = M_i D_i, b_i, Q_i of section 1.5 (6-state).

        ``dK_prev`` is the estimate of dK_{i-1}; with ``heading_linearisation='estimate'`` the heading terms are
        linearised about a_K * dK_prev instead of 0 (paper: 0, i.e. about the measured heading)."""
        aK, qK, aU, qU, _ = self._coeffs(dr.dt_s)
        w2 = self.sigma_w2(dr)
        dt = dr.dt_s
        lin = aK * dK_prev if self.cfg.heading_linearisation == "estimate" else 0.0
        ve, vn, bx, by = self._rotated(dr, lin)
        # Phi = M diag(1, 1, 1, aK, aU, aU) with M = I + dt E (E: (x, dK) = V^N, (x, dU^E) = 1, (y, dK) = -V^E,
        # (y, dU^N) = 1; here ve, vn are already V dt); Q = M diag(0, 0, 0, qK, qU, qU) M^T + diag(w2, w2, 0, ...)
        # written out entry by entry (the same values as the matrix products, without their call overhead)
        Phi = np.array(
            [
                [1.0, 0.0, 0.0, vn * aK, 0.0, dt * aU],
                [0.0, 1.0, 0.0, -ve * aK, dt * aU, 0.0],
                [0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
                [0.0, 0.0, 0.0, aK, 0.0, 0.0],
                [0.0, 0.0, 0.0, 0.0, aU, 0.0],
                [0.0, 0.0, 0.0, 0.0, 0.0, aU],
            ]
        )
        b = np.array([bx + dr.ue_dt_m, by + dr.un_dt_m, 0.0, 0.0, 0.0, 0.0])
        qx, qy, qu = vn * qK, -ve * qK, dt * qU
        Q = np.array(
            [
                [vn * qx + dt * qu + w2, vn * qy, 0.0, qx, 0.0, qu],
                [vn * qy, -ve * qy + dt * qu + w2, 0.0, qy, qu, 0.0],
                [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                [qx, qy, 0.0, qK, 0.0, 0.0],
                [0.0, qu, 0.0, 0.0, qU, 0.0],
                [qu, 0.0, 0.0, 0.0, 0.0, qU],
            ]
        )
        return Phi, b, Q

    def backward(self, dr: DrInterval, dK_next: float = 0.0) -> tuple[F64, F64, F64]:
        """Phi^b = D^b M^b, b^b, Q^b of the backward step s+1 -> s (5-state), with the DR of (t_s, t_{s+1}].

        ``dK_next`` is the estimate of dK_{s+1} (used only with ``heading_linearisation='estimate'``)."""
        aK, qK, aU, qU, _ = self._coeffs(dr.dt_s)
        w2 = self.sigma_w2(dr)
        dt = dr.dt_s
        lin = dK_next if self.cfg.heading_linearisation == "estimate" else 0.0
        ve, vn, bx, by = self._rotated(dr, lin)
        # Phi^b = diag(1, 1, aK, aU, aU) (I - dt E^b), E^b: (x, dK) = V^N, (x, dU^E) = 1, (y, dK) = -V^E, (y, dU^N) = 1
        Phi = np.array(
            [
                [1.0, 0.0, -vn, 0.0, -dt],
                [0.0, 1.0, ve, -dt, 0.0],
                [0.0, 0.0, aK, 0.0, 0.0],
                [0.0, 0.0, 0.0, aU, 0.0],
                [0.0, 0.0, 0.0, 0.0, aU],
            ]
        )
        b = np.array([-(bx + dr.ue_dt_m), -(by + dr.un_dt_m), -0.0, -0.0, -0.0])
        Q = np.diag([w2, w2, qK, qU, qU])
        return Phi, b, Q


class Row(Protocol):
    """One scalar measurement: ``block`` 's' (buffered copy) or 'i' (current), ``group`` shares delta_i."""

    @property
    def block(self) -> str: ...
    @property
    def group(self) -> int: ...
    @property
    def stamp_ns(self) -> int: ...
    @property
    def key(self) -> str: ...
    @property
    def value(self) -> float: ...

    def predict(self, x: float, y: float, dc: float) -> tuple[float, float, float, float]:
        """h and its partial derivatives with respect to x, y and dc."""
        ...

    def hessian_xy(self, x: float, y: float) -> tuple[float, float, float]:
        """Second derivatives (d2h/dx2, d2h/dxdy, d2h/dy2) for the second-order correction."""
        ...


@dataclass(frozen=True)
class RangeRow:
    """Range (1): h = sqrt((x^j-x)^2 + (y^j-y)^2 + (z^j-z)^2) + dc * T, T = measured travel time (s)."""

    block: str
    group: int
    stamp_ns: int
    key: str
    value: float
    bx: float
    by: float
    bz: float
    z: float
    T_s: float

    def predict(self, x: float, y: float, dc: float) -> tuple[float, float, float, float]:
        ex, ey, ez = self.bx - x, self.by - y, self.bz - self.z
        D = math.sqrt(ex * ex + ey * ey + ez * ez)
        # predicted travel time D / c~ (c~ = value / T_s), not the measured one: the measured T_s contains this
        # range's noise, and a Jacobian correlated with the innovation biases the dc update (E[T_s nu] != 0)
        T = D * self.T_s / self.value if self.value > 0.0 else self.T_s
        if D < 1e-9:
            return dc * T, 0.0, 0.0, T
        f = 1.0 + dc * T / D
        return D + dc * T, -ex / D * f, -ey / D * f, T

    def hessian_xy(self, x: float, y: float) -> tuple[float, float, float]:
        """Hessian of the slant range in the horizontal position: (I - g g^T) / D, g = (x - x^j, y - y^j) / D."""
        ex, ey, ez = self.bx - x, self.by - y, self.bz - self.z
        D = math.sqrt(ex * ex + ey * ey + ez * ez)
        if D < 1e-9:
            return 0.0, 0.0, 0.0
        gx, gy = ex / D, ey / D
        return (1.0 - gx * gx) / D, -gx * gy / D, (1.0 - gy * gy) / D


@dataclass(frozen=True)
class LinearRow:
    """A linear measurement h = h0 + hx x + hy y + hdc dc (used by the linear-Gaussian equivalence test U10)."""

    block: str
    group: int
    stamp_ns: int
    key: str
    value: float
    h0: float
    hx: float
    hy: float
    hdc: float

    def predict(self, x: float, y: float, dc: float) -> tuple[float, float, float, float]:
        return self.h0 + self.hx * x + self.hy * y + self.hdc * dc, self.hx, self.hy, self.hdc

    def hessian_xy(self, x: float, y: float) -> tuple[float, float, float]:
        return 0.0, 0.0, 0.0


def noise_cov(groups: list[int], sigma_delta_m: float, sigma_v_m: float) -> F64:
    """R = sigma_delta^2 1 1^T + sigma_v^2 I within one epoch (group), block-diagonal across epochs."""
    if len(groups) == 1:
        return np.array([[sigma_delta_m**2 + sigma_v_m**2]])
    g = np.asarray(groups)
    same = (g[:, None] == g[None, :]).astype(np.float64)
    return sigma_delta_m**2 * same + sigma_v_m**2 * np.eye(g.size)
