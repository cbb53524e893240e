"""Covariance hygiene: symmetrise, take a square root that survives rounding, test positive definiteness.

Rounding makes a propagated covariance ``F P F^T + Q`` or a Joseph update slightly asymmetric; every filter
step therefore ends with

    P <- (P + P^T) / 2

which is exact in IEEE arithmetic for the symmetric part (``a + b == b + a``), so the result is symmetric to
the bit. A square root ``D D^T = P`` for sigma points or sampling uses the Cholesky factor; when rounding has
made P indefinite, :func:`robust_cholesky` adds jitter 1e-9 tr(P)/n I and, failing that, clips the negative
eigenvalues: ``D = V sqrt(max(w, 0))`` with ``P = V diag(w) V^T`` (digest 003 §5.6).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
#: what the toolkit accepts: any float array (float64 in practice; numpy types linalg results loosely)
Floats = NDArray[np.floating[Any]]


def symmetrize(P: Floats) -> FloatArray:
    """(P + P^T) / 2 over the last two axes (one matrix or a batch)."""
    out: FloatArray = 0.5 * (P + transpose(P))
    return out


def transpose(A: Floats) -> FloatArray:
    """A^T over the last two axes: ``A.T`` for one matrix (a view, as ``np.swapaxes`` gives, at a tenth of its
    call cost), ``np.swapaxes(A, -1, -2)`` for a batch."""
    return cast(FloatArray, A.T if A.ndim == 2 else np.swapaxes(A, -1, -2))


def is_positive_definite(P: Floats) -> bool:
    """True if P (n, n) is finite and every eigenvalue of its symmetric part is > 0."""
    return bool(np.isfinite(P).all() and np.all(np.linalg.eigvalsh(P) > 0.0))


def is_cholesky_factorable(P: Floats) -> bool:
    """True if P (n, n) is finite and its Cholesky factorisation (LAPACK dpotrf, lower triangle) succeeds.

    Positive definiteness as a Kalman filter meets it next (a factorisation of P or of S), and cheaper than the
    eigenvalues of :func:`is_positive_definite` (9x9: ~3 us against ~15-50 us on the 2-core VM); the two tests can
    disagree on a matrix at the margin."""
    if not np.isfinite(P).all():
        return False
    return int(_dpotrf()(P, lower=1, clean=0)[1]) == 0


@cache
def _dpotrf() -> Callable[..., tuple[Any, int]]:
    """LAPACK dpotrf, imported on first use: importing scipy.linalg would cost every user of the toolkit."""
    from scipy.linalg.lapack import dpotrf

    return cast(Callable[..., tuple[Any, int]], dpotrf)


@dataclass
class CholeskyStats:
    """Counts of the fallbacks of :func:`robust_cholesky` (jitter, then eigenvalue clipping)."""

    jitter: int = 0
    eig_clip: int = 0

    @property
    def total(self) -> int:
        return self.jitter + self.eig_clip


def robust_cholesky(P: FloatArray, stats: CholeskyStats | None = None) -> FloatArray:
    """Square roots D with D D^T = P for a batch (B, n, n), lower-triangular where P is positive definite.

    On failure: symmetrise, add jitter 1e-9 * |tr(P)|/n * I (1e-12 if tr(P) = 0) and retry; if that fails too,
    use the eigenvalue-clipped square root V sqrt(max(w, 0)). Fallbacks are counted in ``stats``.
    """
    try:
        return np.asarray(np.linalg.cholesky(P), dtype=np.float64)
    except np.linalg.LinAlgError:
        pass
    n = P.shape[-1]
    out = np.empty_like(P)
    eye = np.eye(n)
    for b in range(P.shape[0]):
        Pb = P[b]
        try:
            out[b] = np.linalg.cholesky(Pb)
            continue
        except np.linalg.LinAlgError:
            pass
        Ps = symmetrize(Pb)
        tr = float(np.trace(Ps))
        jitter = 1e-9 * abs(tr) / n if tr != 0.0 else 1e-12
        try:
            out[b] = np.linalg.cholesky(Ps + jitter * eye)
            if stats is not None:
                stats.jitter += 1
            continue
        except np.linalg.LinAlgError:
            pass
        w, V = np.linalg.eigh(Ps)
        out[b] = V * np.sqrt(np.maximum(w, 0.0))[None, :]
        if stats is not None:
            stats.eig_clip += 1
    return out
