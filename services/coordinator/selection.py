"""Active beacon-set selection with hysteresis (digest §4.8 [E]), scored by the full single-cycle error budget.

Cost of an *ordered* set (leader, followers in reply-slot order) over evaluation points p (the moving AUVs'
positions and planned routes over a horizon): ``J = max_p DRMS_CRLB(p)`` (m) with the full R of §4.2/§4.6
(:mod:`.budget`: arrival time, reply jitter, sound speed, node survey, motion compensation). The leader matters:
with the sound-speed term a different leader for the same three beacons can halve the bound.

Search (exact, cheap): the arrival-time-only GDOP of a set is leader-invariant and a lower bound of every ordered
variant's full DRMS (adding positive semi-definite terms to R can only raise the CRLB). With a shared leader
arrival the TDOA Fisher matrix equals the centred TOA form

    F = sum_k u_k u_k^T - (1/|S|) (sum_k u_k)(sum_k u_k)^T        (u_k: horizontal part of the unit vector)

so every set's bound is computed at once; sets are then scored in full (every leader and reply order, schedules
that do not fit T_c at some point excluded, §4.9) in increasing order of their bound until the bound exceeds the
best full cost found. Sets with a point within ``baseline_ext_margin_m`` of a baseline extension (beyond a beacon)
are excluded unless all are. Ties (within 1e-9) go to the shorter cycle max_j (r_1j / c + tau_j), then to the
smallest sum of leader-follower distances, then to the ids.

``cost_model = "arrival_time"`` is the digest's recipe: sets by the GDOP with arrival-time noise only, the leader by
the shortest cycle.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .budget import drms_full, schedule_fits
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
    """Best ordered set of 1 + n_followers beacons for the evaluation points, with hysteresis against ``current``."""
    ids = sorted(beacons)
    k = n_followers + 1
    if len(ids) < k or k < 2:
        return None
    pos = np.array([beacons[i] for i in ids], dtype=np.float64)
    combos = combinations(len(ids), k)
    if points.shape[0] == 0:
        points = np.array([[*pos[:, :2].mean(axis=0), cfg.eval_depth_m]])
    g = gdop_sets(pos, points, combos)
    bound = g.max(axis=1) * cfg.c_mps * cfg.sigma_t_s
    ext = extension_pairs(pos, points, cfg.baseline_ext_margin_m, cfg.baseline_ext_min_beyond_m)
    bad = np.zeros(combos.shape[0], dtype=bool)
    for a, b in itertools.combinations(range(k), 2):
        bad |= ext[combos[:, a], combos[:, b]]
    ranked = np.where(bad, np.inf, bound) if not bad.all() else bound
    taus = list(cfg.tau_slots_s[:n_followers])
    if cfg.cost_model == "arrival_time":
        return _select_arrival_time(ids, pos, combos, ranked, bound, current, cfg, taus)
    best = _best_ordered(ids, pos, points, combos, ranked, cfg, taus)
    if best is None:
        return None
    cost, members, duration = best
    if current is not None and set(current) <= set(ids) and len(current) == k:
        cur_combo = tuple(sorted(ids.index(m) for m in current))
        ci = int(np.flatnonzero((combos == np.array(cur_combo)).all(axis=1))[0])
        if math.isfinite(ranked[ci]):
            cur_cost = float(ordered_cost(current, beacons, points, cfg, taus)[0])
            if math.isfinite(cur_cost) and not cost < (1.0 - cfg.hysteresis) * cur_cost:
                return Selection(
                    members=tuple(current),
                    tau_s=tuple(taus),
                    cost_m=cur_cost,
                    cycle_duration_s=order_duration(tuple(current), beacons, taus, cfg.c_mps),
                )
    return Selection(members=members, tau_s=tuple(taus), cost_m=cost, cycle_duration_s=duration)


def ordered_variants(combo: NDArray[np.int64]) -> NDArray[np.int64]:
    """Every (leader, followers in slot order) of a set: rows of indices, leader first ((k! , k))."""
    return np.array(list(itertools.permutations(combo.tolist())), dtype=np.int64)


def ordered_cost(
    members: tuple[str, ...], beacons: dict[str, F64], points: F64, cfg: CoordinatorConfig, taus: list[float]
) -> F64:
    """(1,) full-budget cost max_p DRMS of one ordered set (leader first); inf if its schedule does not fit T_c."""
    pos = np.array([beacons[m] for m in members], dtype=np.float64)
    lead = np.array([0], dtype=np.int64)
    fol = np.arange(1, len(members), dtype=np.int64)[None, :]
    return _variant_costs(pos, points, lead, fol, cfg, np.asarray(taus, dtype=np.float64))


def _variant_costs(
    pos: F64, points: F64, leaders: NDArray[np.int64], followers: NDArray[np.int64], cfg: CoordinatorConfig, tau: F64
) -> F64:
    d = drms_full(
        pos,
        points,
        leaders,
        followers,
        tau,
        cfg.c_mps,
        cfg.sigma_t_s,
        cfg.sigma_f_s,
        cfg.sigma_c_mps,
        cfg.sigma_node_m,
        cfg.sigma_dr_velocity_mps,
    ).max(axis=1)
    fits = schedule_fits(pos, points, leaders, followers, tau, cfg.c_mps, cfg.cycle_period_s, cfg.t_pkt_s, cfg.guard_s)
    return np.where(fits, d, np.inf)


def _best_ordered(
    ids: list[str],
    pos: F64,
    points: F64,
    combos: NDArray[np.int64],
    ranked: F64,
    cfg: CoordinatorConfig,
    taus: list[float],
    chunk: int = 16,
) -> tuple[float, tuple[str, ...], float] | None:
    """Branch and bound over sets in increasing order of their arrival-time bound; every ordered variant scored."""
    tau = np.asarray(taus, dtype=np.float64)
    order = np.argsort(ranked, kind="stable")
    best: tuple[float, float, float, tuple[str, ...]] | None = None  # (cost, duration, sum r, members)
    for start in range(0, order.size, chunk):
        sets = order[start : start + chunk]
        if best is not None and ranked[sets[0]] > best[0] * (1.0 + 1e-9):
            break
        var = np.vstack([ordered_variants(combos[i]) for i in sets])
        costs = _variant_costs(pos, points, var[:, 0], var[:, 1:], cfg, tau)
        for row, cost in zip(var, costs, strict=True):
            if not math.isfinite(float(cost)) or not math.isfinite(float(ranked[sets[0]])):
                continue
            r = [float(np.linalg.norm(pos[j] - pos[row[0]])) for j in row[1:]]
            dur = max(rj / cfg.c_mps + t for rj, t in zip(r, taus, strict=False))
            members = tuple(ids[i] for i in row)
            key = (float(cost), dur, sum(r), members)
            if best is None or _better(key, best):
                best = key
    if best is None:  # every variant unusable (singular everywhere or no schedule fits): the digest's recipe
        return None
    return best[0], best[3], best[1]


def _better(a: tuple[float, float, float, tuple[str, ...]], b: tuple[float, float, float, tuple[str, ...]]) -> bool:
    """a before b: lower cost (beyond 1e-9 relative), then shorter cycle, shorter baselines, ids."""
    if a[0] < b[0] * (1.0 - 1e-9):
        return True
    if a[0] > b[0] * (1.0 + 1e-9):
        return False
    return (round(a[1], 9), round(a[2], 6), a[3]) < (round(b[1], 9), round(b[2], 6), b[3])


def _select_arrival_time(
    ids: list[str],
    pos: F64,
    combos: NDArray[np.int64],
    ranked: F64,
    cost: F64,
    current: tuple[str, ...] | None,
    cfg: CoordinatorConfig,
    taus: list[float],
) -> Selection:
    """The digest's §4.8 recipe: the set by the arrival-time GDOP, its leader by the shortest cycle."""
    k = combos.shape[1]
    best = int(np.argmin(ranked))
    chosen = combos[best]
    if current is not None and set(current) <= set(ids) and len(current) == k:
        cur_idx = tuple(sorted(ids.index(m) for m in current))
        ci = int(np.flatnonzero((combos == np.array(cur_idx)).all(axis=1))[0])
        if math.isfinite(ranked[ci]) and not ranked[best] < (1.0 - cfg.hysteresis) * ranked[ci]:
            chosen = combos[ci]
            best = ci
    members, duration = order_set([ids[i] for i in chosen], pos[chosen], taus, cfg.c_mps)
    if current is not None and set(current) == set(members):
        members = tuple(current)  # keep the running order for an unchanged set
        beacons = {ids[i]: pos[i] for i in chosen}
        duration = order_duration(members, beacons, taus, cfg.c_mps)
    return Selection(members=members, tau_s=tuple(taus), cost_m=float(cost[best]), cycle_duration_s=duration)


def order_duration(members: tuple[str, ...], beacons: dict[str, F64], taus: list[float], c_mps: float) -> float:
    lead = beacons[members[0]]
    return max(float(np.linalg.norm(beacons[m] - lead)) / c_mps + t for m, t in zip(members[1:], taus, strict=False))
