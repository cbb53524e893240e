"""Filtering steps of the proposed tracker and of its comparison variants (digest 003 §2.4–§2.6).

The "UKF" of the paper = forward UT of the plot (h_a^(3)) + a linear KF in Cartesian coordinates + the
inverse UT (h_b) of the prediction for gating in bistatic coordinates. All functions are batched over
tracks (leading dimension B) and pure.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from shared.filters import kalman
from shared.filters.angles import wrap_pi
from shared.filters.covariance import CholeskyStats, symmetrize
from shared.filters.unscented import TransformResult, moments_from_points, sigma_points, transform

from .geometry import AZ_INDEX, BoolArray, FloatArray, h_a3, h_b
from .models import (
    H_BKF,
    H_POS,
    bkf_process_noise,
    bkf_transition,
    cv_process_noise,
    cv_transition,
    plot_covariance,
)


def predict(x: FloatArray, P: FloatArray, tau: FloatArray, q: float) -> tuple[FloatArray, FloatArray]:
    """x(k|k-1) = F x, P(k|k-1) = F P F^T + Q for each track (tau in s)."""
    return kalman.predict(x, P, cv_transition(tau), cv_process_noise(tau, q))


def _h_b_map(tx: FloatArray, pts: FloatArray) -> FloatArray:
    return h_b(pts, tx)


def bistatic_image(
    x: FloatArray,
    P: FloatArray,
    tx: FloatArray,
    kind: str = "unscented",
    stats: CholeskyStats | None = None,
    with_cross: bool = True,
) -> TransformResult:
    """z_b and its covariance of Cartesian states via the inverse UT (n = 6, 12 points) through h_b."""
    return transform(kind, x, P, partial(_h_b_map, tx), AZ_INDEX, stats, with_cross)


@dataclass
class ConvertedPlots:
    """Plots converted to Cartesian position by the UT (n = 3) through h_a^(3)."""

    y: FloatArray  # (B, 3) m
    R: FloatArray  # (B, 3, 3) m^2
    valid: BoolArray  # (B,) False: D <= 1e-6 even after clamping -> must not be used
    clamped: BoolArray  # (B,) some sigma point had its r_b clamped


def convert_plots(
    z3: FloatArray,
    sig3: FloatArray,
    tx: FloatArray,
    kind: str = "unscented",
    stats: CholeskyStats | None = None,
) -> ConvertedPlots:
    """UT (n = 3) of (r_b, alpha, eps) with diag(sigma^2) through h_a^(3) -> y_a, R_a (digest §2.2)."""
    B = z3.shape[0]
    if B == 0:
        return ConvertedPlots(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0, bool), np.zeros(0, bool))
    R3 = plot_covariance(sig3)
    if kind == "unscented":
        X = sigma_points(z3, R3, stats)
        G, clamped, valid = h_a3(X, tx)
        res = moments_from_points(z3, X, G, with_cross=False)
        return ConvertedPlots(
            res.mean, res.cov, np.asarray(valid.all(axis=1), dtype=bool), np.asarray(clamped.any(axis=1), dtype=bool)
        )
    _, clamped0, valid0 = h_a3(z3, tx)
    res = transform(kind, z3, R3, lambda pts: h_a3(pts, tx)[0])
    return ConvertedPlots(res.mean, res.cov, np.asarray(valid0, dtype=bool), np.asarray(clamped0, dtype=bool))


def kf_position_update(
    x: FloatArray, P: FloatArray, y: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Linear KF update with H = [I_3 0], Joseph form, symmetrised. Returns (x, P, NEES-free NIS_cart)."""
    x_new, P_new, nu, S = kalman.update(x, P, y, H_POS, R)
    return x_new, P_new, kalman.nis(nu, S)


def ukf_bistatic_update(
    x: FloatArray, P: FloatArray, pred: TransformResult, z: FloatArray, R_plot: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """[D] optional extension: UKF update with the 4-D bistatic measurement (uses v_b every scan)."""
    S = symmetrize(pred.cov + R_plot)
    nu = innovation(z, pred.mean)
    K = np.swapaxes(np.linalg.solve(S, np.swapaxes(pred.cross, -1, -2)), -1, -2)
    x_new = x + np.einsum("bij,bj->bi", K, nu)
    P_new = symmetrize(P - K @ S @ np.swapaxes(K, -1, -2))
    return x_new, P_new


def innovation(z: FloatArray, z_pred: FloatArray) -> FloatArray:
    """nu = z - z_pred with the azimuth component wrapped to (-pi, pi]."""
    nu = z - z_pred
    nu[..., AZ_INDEX] = wrap_pi(nu[..., AZ_INDEX])
    return nu


# ----- linear bistatic KF (comparison variant, digest §2.5) ------------------------------------------------


def bkf_predict(
    xb: FloatArray, Pb: FloatArray, tau: FloatArray, q_r: float, q_ang: float
) -> tuple[FloatArray, FloatArray]:
    x_new, P_new = kalman.predict(xb, Pb, bkf_transition(tau), bkf_process_noise(tau, q_r, q_ang))
    x_new[:, 2] = wrap_pi(x_new[:, 2])
    return x_new, P_new


def bkf_measurement(xb: FloatArray, Pb: FloatArray) -> TransformResult:
    """Linear predicted measurement H_b x_b, H_b P_b H_b^T (and cross-covariance P_b H_b^T)."""
    z = xb @ H_BKF.T
    z[:, AZ_INDEX] = wrap_pi(z[:, AZ_INDEX])
    cross = Pb @ H_BKF.T
    return TransformResult(z, symmetrize(H_BKF @ cross), cross)


def bkf_update(xb: FloatArray, Pb: FloatArray, z: FloatArray, R_plot: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Linear KF update of the bistatic state with the 4-D plot (azimuth innovation wrapped), Joseph form."""
    x_new, P_new, _, _ = kalman.update(xb, Pb, z, H_BKF, R_plot, residual=innovation)
    x_new[:, 2] = wrap_pi(x_new[:, 2])
    return x_new, P_new
