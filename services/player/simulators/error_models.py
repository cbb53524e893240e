"""Sensor error processes (numpy, vectorised), each sampled on a uniform grid of period ``dt_s``.

The first-order Gauss-Markov process is :func:`shared.filters.gauss_markov.path`.
"""

from __future__ import annotations

import math

import numpy as np


def white(rng: np.random.Generator, n: int, sigma: float) -> np.ndarray:
    """Independent zero-mean Gaussian samples with standard deviation ``sigma``."""
    return sigma * rng.standard_normal(n)


def random_walk(rng: np.random.Generator, n: int, sigma0: float, q_per_sqrt_s: float, dt_s: float) -> np.ndarray:
    """Random walk: ``x_0 ~ N(0, sigma0^2)``, increments ``N(0, q^2 dt)`` (q in units per sqrt(s))."""
    if n == 0:
        return np.zeros(0)
    steps = rng.standard_normal(n)
    steps[0] *= sigma0
    steps[1:] *= q_per_sqrt_s * math.sqrt(dt_s)
    out: np.ndarray = np.cumsum(steps)
    return out
