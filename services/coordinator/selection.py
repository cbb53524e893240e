"""Active beacon-set selection by GDOP with hysteresis (digest §4.8 [E]).

Cost of a set S over evaluation points p (the moving AUVs' positions and planned routes over a horizon):
``J(S) = max_p GDOP(p; S) * c * sigma_t`` (m), GDOP with receiver arrival-time noise only. With a shared
leader arrival the TDOA Fisher matrix is leader-invariant and equals the centred TOA form

    F = sum_k u_k u_k^T - (1/|S|) (sum_k u_k)(sum_k u_k)^T        (u_k: horizontal part of the unit vector)

so every set is scored at once, vectorised over sets and points. Sets with a point within
``baseline_ext_margin_m`` of a baseline extension (beyond a beacon) are excluded unless all are.
The leader is the member that minimises the cycle duration max_j (r_1j / c + tau_j), ties broken by the
smallest sum of leader-follower distances, then by id.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .config import CoordinatorConfig

F64 = NDArray[np.floating[Any]]


@dataclass(frozen=True)
class Selection:
    """A chosen active set: leader first, followers in reply-slot order."""

    members: tuple[str, ...]
    tau_s: tuple[float, ...]
    cost_m: float
    cycle_duration_s: float

    @property
    def leader(self) -> str:
        return self.members[0]

    @property
    def followers(self) -> tuple[str, ...]:
        return self.members[1:]


def gdop_sets(pos: F64, points: F64, combos: NDArray[np.int64], chunk: int = 2048) -> F64:
    """GDOP of every set (rows of beacon indices) at every point -> (S, P), in cache-sized chunks."""
    d = points[None, :, :] - pos[:, None, :]  # (B, P, 3)
    rng = np.sqrt(np.sum(d * d, axis=2))
    ux = d[:, :, 0] / rng
    uy = d[:, :, 1] / rng
    per_beacon = (ux, uy, ux * ux, ux * uy, uy * uy)
    return np.vstack([_gdop_chunk(per_beacon, combos[i : i + chunk]) for i in range(0, combos.shape[0], chunk)])


def _gdop_chunk(per_beacon: tuple[F64, ...], combos: NDArray[np.int64]) -> F64:
    sums = [q[combos[:, 0]] for q in per_beacon]
    for col in range(1, combos.shape[1]):
        idx = combos[:, col]
        for acc, q in zip(sums, per_beacon, strict=True):
            acc += q[idx]
    sx, sy, sxx, sxy, syy = sums
    k = combos.shape[1]
    fxx = sxx - sx * sx / k
    fxy = sxy - sx * sy / k
    fyy = syy - sy * sy / k
    det = fxx * fyy - fxy * fxy
    ok = det > 1e-15 * (fxx + fyy) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.sqrt((fxx + fyy) / np.where(ok, det, 1.0))
    return np.where(ok, g, np.inf)


@lru_cache(maxsize=64)
def combinations(n: int, k: int) -> NDArray[np.int64]:
    """All k-subsets of range(n) as rows (cached)."""
    flat = np.fromiter(itertools.chain.from_iterable(itertools.combinations(range(n), k)), dtype=np.int64)
    return flat.reshape(-1, k)


def extension_pairs(pos: F64, points: F64, margin_m: float, min_beyond_m: float) -> NDArray[np.bool_]:
    """(B, B) True where some point lies near the extension of baseline (a, b) beyond a or beyond b."""
    B = pos.shape[0]
    if margin_m <= 0.0 or points.shape[0] == 0 or B < 2:
        return np.zeros((B, B), dtype=bool)
    xy = pos[:, :2]
    v = xy[None, :, :] - xy[:, None, :]  # (B, B, 2): a -> b
    L = np.hypot(v[..., 0], v[..., 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        u = v / L[..., None]
    rel = points[None, :, :2] - xy[:, None, :]  # (B, P, 2): a -> point
    along = np.einsum("abi,api->abp", u, rel)
    perp = np.abs(rel[:, None, :, 0] * u[..., 1:2] - rel[:, None, :, 1] * u[..., 0:1])
    beyond = (along < -min_beyond_m) | (along > L[..., None] + min_beyond_m)
    hit = np.any(beyond & (perp < margin_m), axis=2) & (L > 1e-6)
    return hit | hit.T


def order_set(ids: list[str], pos: F64, taus: list[float], c_mps: float) -> tuple[tuple[str, ...], float]:
    """Leader and follower order minimising the cycle duration; returns (members, duration_s)."""
    best: tuple[float, float, tuple[str, ...]] | None = None
    n = len(ids)
    for li in range(n):
        others = [j for j in range(n) if j != li]
        for perm in itertools.permutations(others):
            r = [float(np.linalg.norm(pos[j] - pos[li])) for j in perm]
            dur = max(rj / c_mps + t for rj, t in zip(r, taus, strict=False))
            key = (round(dur, 9), round(sum(r), 6), (ids[li], *(ids[j] for j in perm)))
            if best is None or key < best:
                best = key
    assert best is not None
    return best[2], best[0]


def select(
    beacons: dict[str, F64],
    points: F64,
    current: tuple[str, ...] | None,
    cfg: CoordinatorConfig,
    n_followers: int,
) -> Selection | None:
    """Best set of 1 + n_followers beacons for the evaluation points, with hysteresis against ``current``."""
    ids = sorted(beacons)
    k = n_followers + 1
    if len(ids) < k or k < 2:
        return None
    pos = np.array([beacons[i] for i in ids], dtype=np.float64)
    combos = combinations(len(ids), k)
    if points.shape[0] == 0:
        points = np.array([[*pos[:, :2].mean(axis=0), cfg.eval_depth_m]])
    g = gdop_sets(pos, points, combos)
    cost = g.max(axis=1) * cfg.c_mps * cfg.sigma_t_s
    ext = extension_pairs(pos, points, cfg.baseline_ext_margin_m, cfg.baseline_ext_min_beyond_m)
    bad = np.zeros(combos.shape[0], dtype=bool)
    for a, b in itertools.combinations(range(k), 2):
        bad |= ext[combos[:, a], combos[:, b]]
    ranked = np.where(bad, np.inf, cost) if not bad.all() else cost
    best = int(np.argmin(ranked))
    chosen = combos[best]
    if current is not None and set(current) <= set(ids) and len(current) == k:
        cur_idx = tuple(sorted(ids.index(m) for m in current))
        ci = int(np.flatnonzero((combos == np.array(cur_idx)).all(axis=1))[0])
        if math.isfinite(ranked[ci]) and not ranked[best] < (1.0 - cfg.hysteresis) * ranked[ci]:
            chosen = combos[ci]
            best = ci
    members, duration = order_set([ids[i] for i in chosen], pos[chosen], list(cfg.tau_slots_s[:n_followers]), cfg.c_mps)
    if current is not None and set(current) == set(members):
        members = tuple(current)  # keep the running order for an unchanged set
        duration = order_duration(members, beacons, list(cfg.tau_slots_s[:n_followers]), cfg.c_mps)
    return Selection(
        members=members,
        tau_s=tuple(cfg.tau_slots_s[:n_followers]),
        cost_m=float(cost[best]),
        cycle_duration_s=duration,
    )


def order_duration(members: tuple[str, ...], beacons: dict[str, F64], taus: list[float], c_mps: float) -> float:
    lead = beacons[members[0]]
    return max(float(np.linalg.norm(beacons[m] - lead)) / c_mps + t for m, t in zip(members[1:], taus, strict=False))
