"""The paper's unscented transform (digest §2.2), its first-order counterpart and a robust Cholesky.

Symmetric 2n-point scheme with equal weights 1/(2n) and no central point: sigma points
``X_i = m ± sqrt(n) D[:, i]`` with ``P = D D^T``. Everything is batched over a leading dimension B.
Azimuth outputs are averaged relative to ``f(m)`` with wrapped differences (digest §2.2 [D] Angles), so the
result is invariant under rotation of the scene about the vertical axis.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .geometry import FloatArray, wrap_angle

#: f maps points (..., n) to outputs (..., k)
PointMap = Callable[[FloatArray], FloatArray]


@dataclass
class CholeskyStats:
    """Counts of the Cholesky fallbacks of digest §5.6 (jitter, then eigenvalue clipping)."""

    jitter: int = 0
    eig_clip: int = 0

    @property
    def total(self) -> int:
        return self.jitter + self.eig_clip


def symmetrize(P: FloatArray) -> FloatArray:
    """(P + P^T) / 2 over the last two axes."""
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def robust_cholesky(P: FloatArray, stats: CholeskyStats | None = None) -> FloatArray:
    """Square roots D with D D^T = P for a batch (B, n, n).

    On failure (digest §5.6): symmetrise, add jitter 1e-9 * tr(P)/n * I and retry; if that fails too, use
    an eigenvalue-clipped square root V sqrt(max(w, 0)). Fallbacks are counted in ``stats``.
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


@dataclass
class TransformResult:
    """Mean (B, k), covariance (B, k, k) and input-output cross-covariance (B, n, k) of y = f(x).

    ``cross`` is empty, shape (B, 0, 0), when the caller did not ask for it (``with_cross=False``): only the
    optional 4-D bistatic UKF update uses it, and leaving it out saves a third of the moment computation.
    """

    mean: FloatArray
    cov: FloatArray
    cross: FloatArray


def sigma_points(m: FloatArray, P: FloatArray, stats: CholeskyStats | None = None) -> FloatArray:
    """The 2n symmetric sigma points (B, 2n, n): m + sqrt(n) D[:, i], then m - sqrt(n) D[:, i]."""
    n = m.shape[-1]
    D = robust_cholesky(P, stats)
    off = np.sqrt(n) * np.swapaxes(D, -1, -2)  # row i = column i of D
    return np.concatenate([m[:, None, :] + off, m[:, None, :] - off], axis=1)


def unscented_transform(
    m: FloatArray,
    P: FloatArray,
    f: PointMap,
    az_index: int | None = None,
    stats: CholeskyStats | None = None,
    with_cross: bool = True,
) -> TransformResult:
    """Paper UT of a batch: m (B, n), P (B, n, n) through f; weights 1/(2n), no central point."""
    X = sigma_points(m, P, stats)
    if az_index is None:
        return moments_from_points(m, X, f(X), with_cross=with_cross)
    G = f(np.concatenate([X, m[:, None, :]], axis=1))  # one call: the 2n points and the mean (azimuth ref)
    return moments_from_points(m, X, G[:, :-1, :], az_index, G[:, -1, az_index], with_cross)


def moments_from_points(
    m: FloatArray,
    X: FloatArray,
    G: FloatArray,
    az_index: int | None = None,
    az_ref: FloatArray | None = None,
    with_cross: bool = True,
) -> TransformResult:
    """Equal-weight moments of propagated sigma points G = f(X) (B, 2n, k) around the input mean m.

    With ``az_index``, the azimuth outputs are unwrapped around ``az_ref`` (B,) (normally f(m)) first.
    """
    n = m.shape[-1]
    G = np.array(G, dtype=np.float64, copy=True)
    if az_index is not None:
        ref = az_ref if az_ref is not None else G[:, 0, az_index]
        G[..., az_index] = ref[:, None] + wrap_angle(G[..., az_index] - ref[:, None])
    g = G.mean(axis=1)
    dG = G - g[:, None, :]
    cov = symmetrize(np.einsum("bik,bil->bkl", dG, dG) / (2 * n))
    no_cross = np.zeros((G.shape[0], 0, 0))
    cross = np.einsum("bik,bil->bkl", X - m[:, None, :], dG) / (2 * n) if with_cross else no_cross
    if az_index is not None:
        g[:, az_index] = wrap_angle(g[:, az_index])
    return TransformResult(g, cov, cross)


def numerical_jacobian(m: FloatArray, f: PointMap, az_index: int | None = None) -> FloatArray:
    """Central-difference Jacobian (B, k, n) of f at m (B, n); azimuth differences are wrapped."""
    n = m.shape[-1]
    h = 1e-6 * np.maximum(np.abs(m), 1.0)  # (B, n)
    E = np.eye(n)
    pts = np.concatenate([m[:, None, :] + h[:, None, :] * E, m[:, None, :] - h[:, None, :] * E], axis=1)
    G = f(pts)
    dG = G[:, :n, :] - G[:, n:, :]  # (B, n, k)
    if az_index is not None:
        dG[..., az_index] = wrap_angle(dG[..., az_index])
    return np.swapaxes(dG / (2.0 * h[:, :, None]), -1, -2)


def linearized_transform(m: FloatArray, P: FloatArray, f: PointMap, az_index: int | None = None) -> TransformResult:
    """First-order (EKF-style) counterpart of the UT: y = f(m), P_y = J P J^T (digest §3.4, test C5)."""
    g = f(m).copy()
    J = numerical_jacobian(m, f, az_index)
    cross = P @ np.swapaxes(J, -1, -2)
    cov = symmetrize(J @ cross)
    if az_index is not None:
        g[:, az_index] = wrap_angle(g[:, az_index])
    return TransformResult(g, cov, cross)


def transform(
    kind: str,
    m: FloatArray,
    P: FloatArray,
    f: PointMap,
    az_index: int | None = None,
    stats: CholeskyStats | None = None,
    with_cross: bool = True,
) -> TransformResult:
    """Dispatch on the configured transform: ``"unscented"`` (paper) or ``"linearized"``."""
    if kind == "unscented":
        return unscented_transform(m, P, f, az_index, stats, with_cross)
    if kind == "linearized":
        return linearized_transform(m, P, f, az_index)
    raise ValueError(f"unknown transform {kind!r}")
