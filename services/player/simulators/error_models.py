"""Sensor error processes (numpy, vectorised), each sampled on a uniform grid of period ``dt_s``."""

from __future__ import annotations

import math

import numpy as np


def white(rng: np.random.Generator, n: int, sigma: float) -> np.ndarray:
    """Independent zero-mean Gaussian samples with standard deviation ``sigma``."""
    return sigma * rng.standard_normal(n)


def gauss_markov(rng: np.random.Generator, n: int, sigma: float, tau_s: float, dt_s: float) -> np.ndarray:
    """Stationary first-order Gauss-Markov process, exact discretisation.

    ``x_0 ~ N(0, sigma^2)``, ``x_k = a x_{k-1} + w_k`` with ``a = exp(-dt / tau)`` and
    ``Var w = sigma^2 (1 - a^2)``, so every sample has variance ``sigma^2`` and the autocorrelation is
    ``exp(-|lag| / tau)``.
    """
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


def random_walk(rng: np.random.Generator, n: int, sigma0: float, q_per_sqrt_s: float, dt_s: float) -> np.ndarray:
    """Random walk: ``x_0 ~ N(0, sigma0^2)``, increments ``N(0, q^2 dt)`` (q in units per sqrt(s))."""
    if n == 0:
        return np.zeros(0)
    steps = rng.standard_normal(n)
    steps[0] *= sigma0
    steps[1:] *= q_per_sqrt_s * math.sqrt(dt_s)
    out: np.ndarray = np.cumsum(steps)
    return out
