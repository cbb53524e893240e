"""The bank of vertical Kalman filters, one per hypothesis, vectorised over the whole grid (digest §2.2, S4).

Phi, Q, C, R and P0 are the same for every hypothesis, so the covariance P, the innovation variance S and
the gain K are shared: the Riccati recursion runs once per measurement (3x3 work) and only the state
vectors are per hypothesis, held as one array of shape ``(3, *grid_shape)``. The per-hypothesis work of
one measurement is a handful of whole-array multiply-adds; there is no Python loop over hypotheses.

The shared covariance update is in Joseph form and symmetrised.
"""

from __future__ import annotations

import numpy as np

from shared.filters.covariance import symmetrize

from .geometry import F64
from .models import phi31


class KalmanBank:
    """State vectors of all hypotheses (``x[0]`` = da, ``x[1]`` = dV, ``x[2]`` = dh; the digest's S) and the shared P.

    The shared 3x3 covariance is kept as its six distinct entries in Python floats: the closed forms of
    ``Phi P Phi^T + Q`` and of the Joseph update for C = [0 0 1] cost a few microseconds, where generic
    small-matrix numpy calls would dominate the per-measurement time on a 51 x 51 grid.
    """

    def __init__(
        self,
        shape: tuple[int, ...],
        P0_diag: list[float],
        phi_mode: str = "exact",
        q_a: float = 1e-6,
        q_h: float = 0.0,
    ) -> None:
        self.shape = shape
        self.P0 = np.diag(np.asarray(P0_diag, dtype=np.float64))
        self.phi_mode = phi_mode
        self.q_a = q_a
        self.q_h = q_h
        self.x: F64 = np.zeros((3, *shape))
        self._p = _pack(self.P0)
        self.t_prev: float | None = None
        self._nu: F64 = np.empty(shape)
        self._tmp: F64 = np.empty(shape)
        self._tmp3: F64 = np.empty((3, *shape))

    @property
    def P(self) -> F64:
        """The shared covariance of (da, dV, dh), symmetric by construction."""
        a, b, c, d, e, g = self._p
        return np.array([[a, b, c], [b, d, e], [c, e, g]])

    def reset(self) -> None:
        """Zero states and P = P0 (a start)."""
        self.x.fill(0.0)
        self._p = _pack(self.P0)
        self.t_prev = None

    def predict(self, t: float) -> None:
        """Propagate all states and the shared P to time t with T = t - t_prev (T = 0 at the first call)."""
        T = 0.0 if self.t_prev is None else t - self.t_prev
        self.t_prev = t
        if T <= 0.0:
            return
        x, tmp = self.x, self._tmp
        f = phi31(T, self.phi_mode)
        # dh' = dh + T dV + phi31 da ; dV' = dV + T da ; da' = da  (eq. 3); order matters: dh uses the old dV
        np.multiply(x[1], T, out=tmp)
        x[2] += tmp
        if f != 0.0:
            np.multiply(x[0], f, out=tmp)
            x[2] += tmp
        np.multiply(x[0], T, out=tmp)
        x[1] += tmp
        # Phi P Phi^T + Q in closed form (P = [[a, b, c], [b, d, e], [c, e, g]])
        a, b, c, d, e, g = self._p
        r10, r11, r12 = T * a + b, T * b + d, T * c + e  # row 1 of Phi P
        r20, r21, r22 = f * a + T * b + c, f * b + T * d + e, f * c + T * e + g  # row 2 of Phi P
        qa = self.q_a
        T2 = T * T
        T3 = T2 * T
        self._p = (
            a + qa * T,
            r10 + qa * T2 / 2.0,
            r20 + qa * T3 / 6.0,
            T * r10 + r11 + qa * T3 / 3.0,
            f * r10 + T * r11 + r12 + qa * T3 * T / 8.0,
            f * r20 + T * r21 + r22 + qa * T3 * T2 / 20.0 + self.q_h * T,
        )

    def innovation(self, patch: F64, c: float) -> F64:
        """nu = (patch + c) - dh^- for every hypothesis, into an internal buffer (valid until the next call).

        With c = h_ra - h_ins, ``patch + c`` is the observation y_ij of dh (the innovation is -e_ij of eq. 4).
        """
        nu = self._nu
        np.subtract(patch, self.x[2], out=nu)
        nu += c
        return nu

    def innovation_variance(self, R: float) -> float:
        """S_k = P^-[2,2] + R (shared)."""
        return self._p[5] + R

    def update(self, nu: F64, R: float) -> float:
        """Measurement update of every hypothesis with its innovation ``nu``; returns the shared S_k.

        ``x += K nu`` per hypothesis, K = P[:, 2]/S_k; the shared covariance by the Joseph form
        ``(I - K C) P (I - K C)^T + R K K^T``, which for C = [0 0 1] and p = P[:, 2] expands to
        ``P_ij - K_i p_j - p_i K_j + S_k K_i K_j`` (symmetric by construction).
        """
        a, b, c, d, e, g = self._p
        Sk = g + R
        k0, k1, k2 = c / Sk, e / Sk, g / Sk
        # x[i] += K_i nu for the three states at once (K_i nu == nu K_i exactly: the same values as row by row)
        np.multiply.outer((k0, k1, k2), nu, out=self._tmp3)
        self.x += self._tmp3

        def j(pi: float, pj: float, ki: float, kj: float, pij: float) -> float:
            return pij - ki * pj - pi * kj + Sk * ki * kj

        self._p = (
            j(c, c, k0, k0, a),
            j(c, e, k0, k1, b),
            j(c, g, k0, k2, c),
            j(e, e, k1, k1, d),
            j(e, g, k1, k2, e),
            j(g, g, k2, k2, g),
        )
        return Sk


def _pack(P: F64) -> tuple[float, float, float, float, float, float]:
    Ps = symmetrize(P)
    return (
        float(Ps[0, 0]),
        float(Ps[0, 1]),
        float(Ps[0, 2]),
        float(Ps[1, 1]),
        float(Ps[1, 2]),
        float(Ps[2, 2]),
    )
