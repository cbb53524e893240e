"""First-order Gauss-Markov (exponentially correlated) process: exact and Euler discretisation, stationary paths.

The process de/dt = -e / tau + w(t), stationary standard deviation sigma, autocorrelation sigma^2 exp(-|lag|/tau),
sampled every dt is the AR(1) recursion

    e_k = a e_{k-1} + w_k,    w_k ~ N(0, q)
    exact:  a = exp(-dt / tau),   q = sigma^2 (1 - a^2)       (every sample keeps variance sigma^2)
    Euler:  a = 1 - dt / tau,     q = 2 sigma^2 dt / tau       (first order in dt / tau)

A stationary path starts from e_0 ~ N(0, sigma^2).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .covariance import Floats

FloatArray = NDArray[np.float64]


def discretise(dt_s: float, tau_s: float, sigma: float, form: str = "exact") -> tuple[float, float]:
    """(a, q) of one step of dt_s: the transition coefficient and the variance of the driving noise.

    ``form`` "euler" gives the Euler step, anything else the exact one."""
    if form == "euler":
        a = 1.0 - dt_s / tau_s
        return a, 2.0 * sigma**2 * dt_s / tau_s
    a = math.exp(-dt_s / tau_s)
    return a, sigma**2 * (1.0 - a * a)


def discretise_sd(dt_s: float, tau_s: Floats, sigma: Floats) -> tuple[FloatArray, FloatArray]:
    """Exact (a, sqrt(q)) for several states at once (tau_s, sigma arrays); dt_s < 0 is taken as 0."""
    a = np.exp(-max(dt_s, 0.0) / tau_s)
    return a, sigma * np.sqrt(np.maximum(1.0 - a * a, 0.0))


def path(rng: np.random.Generator, n: int, sigma: float, tau_s: float, dt_s: float) -> FloatArray:
    """A stationary path of n samples, exact discretisation; draws ``rng.standard_normal(n)``."""
    if n == 0:
        return np.zeros(0)
    a = math.exp(-dt_s / tau_s)
    drive = rng.standard_normal(n)
    drive[0] *= sigma
    drive[1:] *= sigma * math.sqrt(1.0 - a * a)
    out = np.empty(n)
    x = 0.0
    for k, w in enumerate(drive.tolist()):  # a plain recursion: ~0.1 us per sample, no scipy import
        x = a * x + w
        out[k] = x
    return out
