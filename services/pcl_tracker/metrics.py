"""Per-run and aggregate Monte-Carlo metrics of the PCL tracker, as plain dicts.

* OSPA distance per scan (Schuhmacher et al. 2008) between confirmed track positions and true positions,
  with cut-off ``c`` (m) and order ``p``, solved with scipy's assignment solver;
* position / velocity errors of the track matched to each target, per scan (for RMSE over time);
* track continuity: id swaps (a target's matched track id changes) and breaks (a live target loses its
  matched track), distinct ids per target;
* false confirmed tracks: confirmed track ids never matched to any target while confirmed.

Matching: at each scan, confirmed tracks are assigned to live targets by minimum total 3-D distance with
``linear_sum_assignment``; pairs farther apart than ``match_distance_m`` are not matches.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from schemas.pcl_tracker import PclScanReport

from .geometry import FloatArray


def ospa(X: FloatArray, Y: FloatArray, c: float, p: float = 2.0) -> float:
    """OSPA distance between point sets X (m, d) and Y (n, d) with cut-off c and order p."""
    X = np.asarray(X, dtype=np.float64)
    Y = np.asarray(Y, dtype=np.float64)
    if X.ndim != 2 or Y.ndim != 2:
        raise ValueError("point sets must be 2-D arrays (points, dimensions)")
    m, n = X.shape[0], Y.shape[0]
    if m == 0 and n == 0:
        return 0.0
    if m == 0 or n == 0:
        return float(c)
    if m > n:
        X, Y, m, n = Y, X, n, m
    D = np.minimum(np.linalg.norm(X[:, None, :] - Y[None, :, :], axis=-1), c) ** p
    r, k = linear_sum_assignment(D)
    total = float(D[r, k].sum()) + (c**p) * (n - m)
    return float((total / n) ** (1.0 / p))


def match_tracks(track_pos: FloatArray, truth_pos: FloatArray, max_distance_m: float) -> list[tuple[int, int]]:
    """Assignment of tracks (rows) to targets (cols) by least total distance; pairs beyond the limit dropped."""
    if track_pos.shape[0] == 0 or truth_pos.shape[0] == 0:
        return []
    dist = np.linalg.norm(track_pos[:, None, :] - truth_pos[None, :, :], axis=-1)
    near = dist <= max_distance_m
    big = 1e3 * max_distance_m + float(dist.max())
    r, k = linear_sum_assignment(np.where(near, dist, big))
    return [(int(i), int(j)) for i, j in zip(r, k, strict=True) if near[i, j]]


def run_metrics(
    reports: Sequence[PclScanReport],
    true_states: FloatArray,
    scan_ids: Sequence[int],
    *,
    ospa_c_m: float = 1000.0,
    ospa_p: float = 2.0,
    match_distance_m: float = 1000.0,
) -> dict[str, Any]:
    """Metrics of one run. ``true_states`` (T, n_targets, 6) (NaN = target absent) at ``scan_ids`` (T,)."""
    by_scan = {r.scan_id: r for r in reports if r.trigger == "scan"}
    T, n_tgt, _ = true_states.shape
    ospa_t: list[float] = []
    pos_sq = np.zeros(T)
    vel_sq = np.zeros(T)
    n_matched = np.zeros(T, dtype=np.int64)
    n_alive = np.zeros(T, dtype=np.int64)
    prev: dict[int, int] = {}
    swaps = breaks = 0
    ids_per_target: dict[int, set[int]] = {i: set() for i in range(n_tgt)}
    confirmed_ids: set[int] = set()
    matched_ids: set[int] = set()
    final_matched: list[bool] = [False] * n_tgt
    for k, sid in enumerate(scan_ids):
        alive_idx = [i for i in range(n_tgt) if np.all(np.isfinite(true_states[k, i]))]
        n_alive[k] = len(alive_idx)
        truth = true_states[k, alive_idx] if alive_idx else np.zeros((0, 6))
        rep = by_scan.get(sid)
        conf = [t for t in rep.tracks if t.status == "CONFIRMED"] if rep is not None else []
        states = np.array([t.state_enu for t in conf], dtype=np.float64).reshape(-1, 6)
        confirmed_ids.update(t.track_id for t in conf)
        ospa_t.append(ospa(states[:, :3], truth[:, :3], ospa_c_m, ospa_p))
        cur: dict[int, int] = {}
        for ti, gj in match_tracks(states[:, :3], truth[:, :3], match_distance_m):
            tgt = alive_idx[gj]
            tid = conf[ti].track_id
            cur[tgt] = tid
            matched_ids.add(tid)
            ids_per_target[tgt].add(tid)
            e = states[ti] - truth[gj]
            pos_sq[k] += float(e[:3] @ e[:3])
            vel_sq[k] += float(e[3:] @ e[3:])
            n_matched[k] += 1
        for tgt, tid in prev.items():
            if tgt not in alive_idx:
                continue
            if tgt not in cur:
                breaks += 1
            elif cur[tgt] != tid:
                swaps += 1
        prev = cur
        if k == T - 1:
            final_matched = [i in cur for i in range(n_tgt)]
    return {
        "ospa_m": ospa_t,
        "ospa_mean_m": float(np.mean(ospa_t)) if ospa_t else 0.0,
        "pos_sq_err_m2": pos_sq.tolist(),
        "vel_sq_err_m2s2": vel_sq.tolist(),
        "n_matched": n_matched.tolist(),
        "n_alive": n_alive.tolist(),
        "coverage": float(n_matched.sum() / max(n_alive.sum(), 1)),
        "id_swaps": swaps,
        "breaks": breaks,
        "track_ids_per_target": {str(k): sorted(v) for k, v in ids_per_target.items()},
        "n_confirmed_tracks": len(confirmed_ids),
        "false_confirmed_tracks": len(confirmed_ids - matched_ids),
        "final_matched": final_matched,
    }


def aggregate(runs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Monte-Carlo aggregate of :func:`run_metrics` dicts (RMSE over runs per scan, means of counts)."""
    if not runs:
        return {"n_runs": 0}
    pos = np.sum([r["pos_sq_err_m2"] for r in runs], axis=0)
    vel = np.sum([r["vel_sq_err_m2s2"] for r in runs], axis=0)
    n = np.sum([r["n_matched"] for r in runs], axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        pos_rmse = np.where(n > 0, np.sqrt(pos / np.maximum(n, 1)), np.nan)
        vel_rmse = np.where(n > 0, np.sqrt(vel / np.maximum(n, 1)), np.nan)
    ospa_t = np.mean([r["ospa_m"] for r in runs], axis=0)
    finals = np.array([r["final_matched"] for r in runs], dtype=float)
    return {
        "n_runs": len(runs),
        "pos_rmse_m": [float(v) for v in pos_rmse],
        "vel_rmse_mps": [float(v) for v in vel_rmse],
        "ospa_mean_m_per_scan": [float(v) for v in ospa_t],
        "ospa_mean_m": float(np.mean(ospa_t)),
        "coverage": float(np.mean([r["coverage"] for r in runs])),
        "id_swaps_per_run": float(np.mean([r["id_swaps"] for r in runs])),
        "breaks_per_run": float(np.mean([r["breaks"] for r in runs])),
        "false_confirmed_tracks_per_run": float(np.mean([r["false_confirmed_tracks"] for r in runs])),
        "final_track_fraction": float(finals.mean()) if finals.size else 0.0,
    }
