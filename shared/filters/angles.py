"""Angle wrapping, radians unless the name says degrees.

Three formulas for the principal interval exist in the estimators, and all are kept (the formula decides the
last bit of every wrapped value):

* :func:`wrap_pi` -> (-pi, pi]:  ``pi - ((pi - a) mod 2 pi)``  (bearings, azimuths, innovations)
* :func:`wrap_pi_left` -> [-pi, pi): ``((a + pi) mod 2 pi) - pi``  (error statistics of the player)
* :func:`wrap_pi_shifted` -> (-pi, pi]: ``((a + pi) mod 2 pi) - pi`` with -pi mapped to pi  (the attitude
  estimator's angle differences; the radian form of :func:`wrap_deg_180`)

``np.mod`` returns a value in [0, 2 pi) up to one rounding, so a result may land on the excluded end point
(-pi for :func:`wrap_pi`, pi for :func:`wrap_pi_left`) when ``a`` is within an ulp of it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

TWO_PI = 2.0 * np.pi


def wrap_pi(a: ArrayLike) -> FloatArray:
    """Wrap angles (rad) to (-pi, pi]: pi - ((pi - a) mod 2 pi)."""
    arr = np.asarray(a, dtype=np.float64)
    return np.pi - np.mod(np.pi - arr, TWO_PI)


def wrap_pi_left(a: ArrayLike) -> FloatArray:
    """Wrap angles (rad) to [-pi, pi): ((a + pi) mod 2 pi) - pi."""
    out: FloatArray = np.mod(np.asarray(a, dtype=np.float64) + np.pi, TWO_PI) - np.pi
    return out


def wrap_pi_shifted(a: ArrayLike) -> FloatArray:
    """Wrap angles (rad) to (-pi, pi]: ((a + pi) mod 2 pi) - pi, with -pi mapped to pi."""
    w = wrap_pi_left(a)
    return np.where(w == -np.pi, np.pi, w)


def wrap_2pi(a: ArrayLike) -> FloatArray:
    """Wrap angles (rad) to [0, 2 pi): a mod 2 pi, with a rounded 2 pi mapped to 0."""
    w = np.mod(np.asarray(a, dtype=np.float64), TWO_PI)
    return np.where(w >= TWO_PI, 0.0, w)


def wrap_deg_180(a: ArrayLike) -> FloatArray:
    """Wrap angles (deg) to (-180, 180]: ((a + 180) mod 360) - 180, with -180 mapped to 180."""
    w = np.asarray(np.mod(np.asarray(a, dtype=np.float64) + 180.0, 360.0) - 180.0)
    return np.where(w == -180.0, 180.0, w)
