"""Particle resampling (Douc, Cappé & Moulines 2005) and the effective sample size.

With normalised weights w_1..w_N and their cumulative sums c_j = w_1 + ... + w_j (c_N set to 1 so rounding
cannot leave the last bin short), the i-th resampled particle is index_i = min{ j : c_j > u_i } with

    systematic:  u_i = (u + i) / N,    one u ~ U[0, 1) for all i      (i = 0..N-1)
    stratified:  u_i = (u_i' + i) / N, an independent u_i' ~ U[0, 1) per i

Both are unbiased (E[copies of j] = N w_j) and copy particle j either floor(N w_j) or ceil(N w_j) times
(systematic) / with variance below multinomial resampling (stratified).

    N_eff = 1 / sum_j w_j^2          1 for a single surviving particle, N for equal weights
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .covariance import Floats

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]


def _select(w: Floats, u: FloatArray) -> IntArray:
    n = w.size
    cs = np.cumsum(w)
    cs[-1] = 1.0
    return np.minimum(np.searchsorted(cs, u, side="right"), n - 1)


def systematic_resample(w: Floats, rng: np.random.Generator) -> IntArray:
    """Indices of the systematic resample of normalised weights w (N,); draws one ``rng.random()``."""
    n = w.size
    return _select(w, (rng.random() + np.arange(n)) / n)


def stratified_resample(w: Floats, rng: np.random.Generator) -> IntArray:
    """Indices of the stratified resample of normalised weights w (N,); draws ``rng.random(N)``."""
    n = w.size
    return _select(w, (rng.random(n) + np.arange(n)) / n)


def effective_sample_size(w: Floats) -> float:
    """N_eff = 1 / sum w^2 of normalised weights."""
    return float(1.0 / np.sum(w * w))
