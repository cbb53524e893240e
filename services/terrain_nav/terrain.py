"""Synthetic terrain for tests and simulation (digest §4 harness, §5.2).

Roughness is specified at **cell scale**: every generator scales its result so that the RMS height change
between adjacent cells, sqrt(D1), hits a target (12 m for "informative", 0.3 m for "flat").

* :func:`fbm_2d`: 2-D fractional Brownian surface by spectral synthesis (power spectrum ~ |k|^-(2H+2));
* :func:`fbm_1d`: the 1-D profile g used by the ridge and periodic types;
* :func:`make_terrain`: the named types ``informative``, ``flat``, ``ridge_x``, ``ridge_z``, ``periodic``.

Heights are relative; :func:`make_terrain` adds ``base_m`` so that the terrain sits above the datum.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy.fft import next_fast_len

from .geometry import F64

TerrainType = Literal["informative", "flat", "ridge_x", "ridge_z", "periodic"]
TERRAIN_TYPES: tuple[TerrainType, ...] = ("informative", "flat", "ridge_x", "ridge_z", "periodic")


def rms_increment(h: F64) -> float:
    """sqrt(D1) of a grid: RMS adjacent-cell height change, with D1 = mean 0.5*(dx^2 + dz^2) (§2.12)."""
    if h.ndim == 1:
        return float(np.sqrt(np.mean(np.diff(h) ** 2)))
    dx = h[1:, :-1] - h[:-1, :-1]
    dz = h[:-1, 1:] - h[:-1, :-1]
    return float(np.sqrt(np.mean(0.5 * (dx * dx + dz * dz))))


def _spectral(shape: tuple[int, ...], H: float, rng: np.random.Generator, corr_cells: float | None = None) -> F64:
    """Gaussian field with amplitude spectrum |k|^-(H + d/2), on a grid >= 2x the shape, cropped to shape.

    Spectral synthesis: complex white noise in the frequency domain (which is what the FFT of white noise
    is) times |k|^-(H + d/2), inverse FFT, crop. The half-spectrum (``irfftn``) form gives the real field
    directly. 2-D: power ~ |k|^-(2H+2); 1-D: power ~ |k|^-(2H+1).
    """
    big = tuple(int(next_fast_len(2 * n)) for n in shape)
    freqs = [np.fft.fftfreq(n) for n in big[:-1]] + [np.fft.rfftfreq(big[-1])]
    grids = np.meshgrid(*freqs, indexing="ij", sparse=True)
    k2 = sum(g * g for g in grids)
    if corr_cells is not None:  # von Karman: flat spectrum below k_c = 1/corr (correlation length, cells)
        k2 = k2 + (1.0 / corr_cells) ** 2
    k2.flat[0] = 1.0
    amp = np.power(k2, -(H + len(shape) / 2.0) / 2.0)
    amp.flat[0] = 0.0  # no mean
    noise = rng.standard_normal(amp.shape) + 1j * rng.standard_normal(amp.shape)
    field = np.fft.irfftn(noise * amp, s=big, axes=tuple(range(len(big))))
    out: F64 = field[tuple(slice(0, n) for n in shape)]
    return out


def fbm_2d(
    shape: tuple[int, int],
    rng: np.random.Generator,
    H: float = 0.6,
    rms_inc_m: float = 12.0,
    corr_cells: float | None = None,
) -> F64:
    """2-D fBm surface (zero mean) with RMS adjacent-cell increment ``rms_inc_m``; with ``corr_cells`` a von
    Karman surface (fBm below that scale, uncorrelated beyond it: power ~ (|k|^2 + 1/corr^2)^-(H+1))."""
    h = _spectral(shape, H, rng, corr_cells)
    h -= h.mean()
    out: F64 = h * (rms_inc_m / rms_increment(h))
    return out


def fbm_1d(n: int, rng: np.random.Generator, H: float = 0.6, rms_inc_m: float = 12.0) -> F64:
    """1-D fBm profile (zero mean) with RMS adjacent-sample increment ``rms_inc_m``."""
    g = _spectral((n,), H, rng)
    g -= g.mean()
    out: F64 = g * (rms_inc_m / rms_increment(g))
    return out


def make_terrain(
    kind: TerrainType,
    shape: tuple[int, int],
    rng: np.random.Generator,
    H: float = 0.6,
    rms_inc_m: float = 12.0,
    flat_rms_inc_m: float = 0.3,
    periodic_amp_m: float = 40.0,
    periodic_cells: float = 10.0,
    base_m: float = 500.0,
    corr_cells: float | None = None,
) -> F64:
    """Cell-centre heights of one of the digest's terrain types (axis 0 = x, axis 1 = z), metres.

    ``ridge_z``: h = g(z) only (no along-track information); ``ridge_x``: h = g(x) only (no cross-track
    information); ``periodic``: h = A sin(2 pi x / (P cell)) + g(z), an along-track ambiguity of period P.
    """
    n_i, n_j = shape
    if kind == "informative":
        h = fbm_2d(shape, rng, H, rms_inc_m, corr_cells)
    elif kind == "flat":
        h = fbm_2d(shape, rng, H, flat_rms_inc_m)
    elif kind == "ridge_z":
        h = np.broadcast_to(fbm_1d(n_j, rng, H, rms_inc_m)[None, :], shape).copy()
    elif kind == "ridge_x":
        h = np.broadcast_to(fbm_1d(n_i, rng, H, rms_inc_m)[:, None], shape).copy()
    elif kind == "periodic":
        x_cells = np.arange(n_i, dtype=np.float64) + 0.5
        wave = periodic_amp_m * np.sin(2.0 * np.pi * x_cells / periodic_cells)
        h = wave[:, None] + fbm_1d(n_j, rng, H, rms_inc_m)[None, :]
    else:  # pragma: no cover - guarded by the Literal type
        raise ValueError(f"unknown terrain type {kind!r}")
    out: F64 = np.ascontiguousarray(h + base_m - float(np.min(h)), dtype=np.float64)
    return out
