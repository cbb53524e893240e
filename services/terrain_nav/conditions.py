"""The four reliability (plausibility) conditions C1-C4 (digest §2.5), as pure functions.

All four are necessary: a fix is issued only when every one holds.

* C1 ``N_valid > N_min`` (or ``>=``): enough valid measurements;
* C2 ``F_min/N_valid < mu_F * L_zk``: goodness of fit of the best hypothesis;
* C3 ``D_max < mu1 + mu2 * phi(N_valid)``: the near-minimum set ``F <= F_min*(1+mu3)`` is small, D_max
  being the largest distance (cells) from the argmin to **any** qualifying cell (distant minima count);
* C4 ``R_min < R_thr`` (or ``<=``): the argmin's bounding-box extent over the last N_R measurements.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from .geometry import F64


def argmin_2d(F: F64) -> tuple[int, int, float]:
    """Array index (a, b) of the minimum of F (first in C order on ties) and F_min."""
    k = int(np.argmin(F))
    a, b = divmod(k, F.shape[1])
    return a, b, float(F[a, b])


def c1_enough_data(n_valid: int, N_min: int, strict: bool = True) -> bool:
    """C1: N_valid > N_min (strict, the chosen reading) or N_valid >= N_min."""
    return n_valid > N_min if strict else n_valid >= N_min


def c2_fit(F_min: float, n_valid: int, mu_F: float, L_zk: float) -> bool:
    """C2: F_min/N_valid < mu_F * L_zk (False with no valid measurement)."""
    return n_valid > 0 and F_min / n_valid < mu_F * L_zk


def d_max(
    F: F64,
    a: int,
    b: int,
    mu3: float,
    F_min: float | None = None,
    floor: float | None = None,
    gap_cap: float | None = None,
    cap_beyond: float = 0.0,
) -> float:
    """D_max: largest Euclidean distance (cells) from (a, b) to any cell with F <= F_min*(1+mu3).

    With ``floor`` (the sum of the window's expected e^2 at the true hypothesis, m^2) the region is
    F <= F_min + mu3*max(F_min, floor): a minimum that fits better than the noise the model expects cannot
    shrink the region below the noise scale (docs/terrain_nav.md, false fixes on coarse maps). With ``gap_cap``
    (m^2) a cell farther than ``cap_beyond`` cells (Euclidean) from (a, b) qualifies only if also
    F - F_min <= ``gap_cap`` (the evidence bound of ``c3_evidence``: distant minima); nearer cells keep the region
    above.
    """
    fmin = float(F[a, b]) if F_min is None else F_min
    bound = fmin * (1.0 + mu3) if floor is None else fmin + mu3 * max(fmin, floor)
    ii, jj = np.nonzero(bound >= F)  # "<=" so the argmin itself always qualifies
    if ii.size == 0:
        return 0.0
    d2 = (ii - a) ** 2 + (jj - b) ** 2
    if gap_cap is not None:
        keep = (d2 <= cap_beyond**2) | (fmin + gap_cap >= F[ii, jj])
        d2 = d2[keep]  # the argmin itself is always kept
    return float(np.sqrt(d2.max()))


def evidence_gap(tau: float, s_expected: list[float], F_min: float, n_valid: int) -> float:
    """The gap 2*tau*s of ``c3_evidence``: hypotheses whose F exceeds F_min by more have a likelihood below
    exp(-tau) times the argmin's, with s = max(median of the window's S_k, F_min/N_valid) the noise per
    measurement (the median ignores the start's S_k of the unknown dh; F_min/N_valid covers noise above the model's).
    """
    pos = [v for v in s_expected if v > 0.0]
    s = max(float(np.median(pos)) if pos else 0.0, F_min / n_valid if n_valid > 0 else 0.0)
    return 2.0 * tau * s


def phi_of(n_valid: int, N_min: int, N_max: int, kind: str = "n_over_nmax") -> float:
    """phi(N) of C3: N/N_max (default), N_max/N or (N - N_min)/(N_max - N_min)."""
    if kind == "n_over_nmax":
        return n_valid / N_max
    if kind == "nmax_over_n":
        return N_max / n_valid if n_valid > 0 else 0.0
    if kind == "linear_min_max":
        return (n_valid - N_min) / (N_max - N_min)
    raise ValueError(f"unknown phi {kind!r}")


def d_threshold(n_valid: int, N_min: int, N_max: int, mu1: float, mu2: float, kind: str = "n_over_nmax") -> float:
    """C3 threshold mu1 + mu2 * phi(N_valid), cells."""
    return mu1 + mu2 * phi_of(n_valid, N_min, N_max, kind)


def c3_unique(D: float, D_thr: float) -> bool:
    """C3: D_max < threshold."""
    return D_thr > D


def r_min(history: Iterable[tuple[int, int, int]], total_meas: int, N_R: int) -> int:
    """R_min: ``max(range(i*), range(j*))`` over history entries (n_at_eval, i*, j*) with n > total - N_R."""
    recent = [(i, j) for (n, i, j) in history if n > total_meas - N_R]
    if not recent:
        return 0
    ii = [i for i, _ in recent]
    jj = [j for _, j in recent]
    return max(max(ii) - min(ii), max(jj) - min(jj))


def c4_stable(R: float, R_thr: float, strict: bool = True) -> bool:
    """C4: R_min < R_thr (strict, the literal reading) or R_min <= R_thr."""
    return R_thr > R if strict else R_thr >= R
