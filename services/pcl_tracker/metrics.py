"""Per-run and aggregate Monte-Carlo metrics of the PCL tracker, as plain dicts.

* OSPA distance per scan (Schuhmacher et al. 2008) between confirmed track positions and true positions,
  with cut-off ``c`` (m) and order ``p``, solved with scipy's assignment solver;
* GOSPA per scan (Rahmathullah, García-Fernández & Svensson 2017, alpha = 2) and its decomposition into
  localisation error (sum of d^p over assigned pairs), missed targets and false tracks;
* track-to-truth association over time (CLEAR MOT, Bernardin & Stiefelhagen 2008): at each scan a target
  keeps the track it had at the previous scan while that track is within ``match_distance_m``; the other
  targets and tracks are paired by least total distance (``linear_sum_assignment``), pairs farther than
  ``match_distance_m`` are not matches. From that association (:func:`identity_metrics`):

  - ``id_switches`` (MOT's IDSW): a target matched to another track than the one it was last matched to;
    each is either an ``id_swaps`` (identity exchanged between targets: the new track was matched to another
    target before, or the old one is matched to another target now) or an ``id_restarts`` (the target's
    track was replaced by a track that never followed another target: a re-initiation);
  - ``fragmentations`` (Li, Huang & Nevatia 2009, as py-motmetrics counts them): a target tracked, then not
    tracked on at least one scan while it exists, then tracked again;
  - ``breaks``: a target tracked at a scan and not at the next one while it exists;
* position / velocity errors, NEES of the matched track, and the NIS of its associated plot, per scan;
* false confirmed tracks: confirmed track ids never matched to any target while confirmed;
* ``assignment_changes``: the former ``id_swaps`` count (the per-scan least-distance matching, without the
  previous scan's pairs, changed a target's track id), kept to compare with earlier figures: it also counts
  restarts and the momentary re-pairings of crossing targets.
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


def gospa(X: FloatArray, Y: FloatArray, c: float, p: float = 2.0) -> dict[str, float]:
    """GOSPA (alpha = 2) between truths X (m, d) and estimates Y (n, d), and its decomposition.

    d_p^(c,2)(X, Y)^p = min over assignments gamma of  sum_{(i,j) in gamma} d(x_i, y_j)^p + c^p/2 (m + n - 2|gamma|),
    with only pairs at d < c assigned (a pair at d >= c costs no less than leaving both unassigned).
    Returns ``gospa`` (the distance), ``localisation`` (sum of d^p over the assigned pairs), ``missed``
    (truths unassigned) and ``false`` (estimates unassigned); gospa^p = localisation + c^p/2 (missed + false).
    """
    X = np.asarray(X, dtype=np.float64)
    Y = np.asarray(Y, dtype=np.float64)
    if X.ndim != 2 or Y.ndim != 2:
        raise ValueError("point sets must be 2-D arrays (points, dimensions)")
    m, n = X.shape[0], Y.shape[0]
    loc, n_pairs = 0.0, 0
    if m and n:
        D = np.linalg.norm(X[:, None, :] - Y[None, :, :], axis=-1) ** p
        C = np.minimum(D, c**p)
        r, k = linear_sum_assignment(C)
        assigned = D[r, k] < c**p
        loc = float(D[r, k][assigned].sum())
        n_pairs = int(assigned.sum())
    missed, false = m - n_pairs, n - n_pairs
    total = loc + 0.5 * c**p * (missed + false)
    return {"gospa": float(total ** (1.0 / p)), "localisation": loc, "missed": float(missed), "false": float(false)}


def mot_matching(
    truth: dict[int, FloatArray], tracks: dict[int, FloatArray], previous: dict[int, int], threshold_m: float
) -> dict[int, int]:
    """One scan of the CLEAR MOT association: target -> track id.

    ``truth`` / ``tracks``: id -> position (m) at this scan; ``previous``: the matches of the previous scan.
    A previous pair is kept while both exist and are within ``threshold_m``; the rest are paired by least total
    distance with pairs beyond ``threshold_m`` excluded.
    """
    out: dict[int, int] = {}
    for i, h in previous.items():
        if i in truth and h in tracks and float(np.linalg.norm(truth[i] - tracks[h])) <= threshold_m:
            out[i] = h
    free_t = [i for i in truth if i not in out]
    used = set(out.values())
    free_h = [h for h in tracks if h not in used]
    if free_t and free_h:
        T = np.array([truth[i] for i in free_t])
        H = np.array([tracks[h] for h in free_h])
        for hi, ti in match_tracks(H, T, threshold_m):
            out[free_t[ti]] = free_h[hi]
    return out


def identity_metrics(
    truth: Sequence[dict[int, FloatArray]], tracks: Sequence[dict[int, FloatArray]], threshold_m: float
) -> dict[str, Any]:
    """ID switches (split into swaps and restarts), fragmentations and breaks over a run (module doc).

    ``truth[k]`` / ``tracks[k]``: id -> position at scan k (only what exists then). Returns the counts and the
    matches of every scan (``matches[k]``: target -> track id).
    """
    prev: dict[int, int] = {}
    last: dict[int, int] = {}  # target -> track it was last matched to (any earlier scan)
    followed: dict[int, set[int]] = {}  # track -> targets it has been matched to
    was_tracked: dict[int, bool] = {}  # target -> tracked at its previous scan of existence
    ever: set[int] = set()
    switches = swaps = restarts = frags = breaks = 0
    matches: list[dict[int, int]] = []
    for truth_k, tracks_k in zip(truth, tracks, strict=True):
        cur = mot_matching(truth_k, tracks_k, prev, threshold_m)
        owner = {h: i for i, h in cur.items()}
        for i, h in cur.items():
            old = last.get(i)
            if old is not None and old != h:
                switches += 1
                if (followed.get(h, set()) - {i}) or owner.get(old, i) != i:
                    swaps += 1
                else:
                    restarts += 1
            if i in ever and not was_tracked.get(i, True):
                frags += 1
        for i in truth_k:
            tracked = i in cur
            if was_tracked.get(i, False) and not tracked:
                breaks += 1
            was_tracked[i] = tracked
        for i, h in cur.items():
            last[i] = h
            followed.setdefault(h, set()).add(i)
            ever.add(i)
        prev = cur
        matches.append(cur)
    return {
        "id_switches": switches,
        "id_swaps": swaps,
        "id_restarts": restarts,
        "fragmentations": frags,
        "breaks": breaks,
        "matches": matches,
    }


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
    gospa_t: list[dict[str, float]] = []
    pos_sq = np.zeros(T)
    vel_sq = np.zeros(T)
    nees = np.zeros(T)
    nis = np.zeros(T)
    n_nis = np.zeros(T, dtype=np.int64)
    n_matched = np.zeros(T, dtype=np.int64)
    n_alive = np.zeros(T, dtype=np.int64)
    ids_per_target: dict[int, set[int]] = {i: set() for i in range(n_tgt)}
    confirmed_ids: set[int] = set()
    matched_ids: set[int] = set()
    final_matched: list[bool] = [False] * n_tgt
    truth_frames: list[dict[int, FloatArray]] = []
    track_frames: list[dict[int, FloatArray]] = []
    confirmed_of_scan: list[dict[int, Any]] = []
    changes = 0
    prev_plain: dict[int, int] = {}
    for k, sid in enumerate(scan_ids):
        alive_idx = [i for i in range(n_tgt) if np.all(np.isfinite(true_states[k, i]))]
        n_alive[k] = len(alive_idx)
        truth = true_states[k, alive_idx] if alive_idx else np.zeros((0, 6))
        rep = by_scan.get(sid)
        conf = [t for t in rep.tracks if t.status == "CONFIRMED"] if rep is not None else []
        states = np.array([t.estimate.mean for t in conf], dtype=np.float64).reshape(-1, 6)
        confirmed_ids.update(t.track_id for t in conf)
        ospa_t.append(ospa(states[:, :3], truth[:, :3], ospa_c_m, ospa_p))
        gospa_t.append(gospa(truth[:, :3], states[:, :3], ospa_c_m, ospa_p))
        truth_frames.append({i: true_states[k, i, :3] for i in alive_idx})
        track_frames.append({t.track_id: states[n, :3] for n, t in enumerate(conf)})
        confirmed_of_scan.append({t.track_id: t for t in conf})
        # the former count: per-scan matching only, a changed id is a "swap"
        plain = {alive_idx[g]: conf[h].track_id for h, g in match_tracks(states[:, :3], truth[:, :3], match_distance_m)}
        changes += sum(1 for i, h in prev_plain.items() if i in plain and plain[i] != h)
        prev_plain = plain
    ident = identity_metrics(truth_frames, track_frames, match_distance_m)
    for k, cur in enumerate(ident["matches"]):
        for tgt, tid in cur.items():
            tr = confirmed_of_scan[k][tid]
            matched_ids.add(tid)
            ids_per_target[tgt].add(tid)
            e = np.asarray(tr.estimate.mean, dtype=np.float64) - true_states[k, tgt]
            pos_sq[k] += float(e[:3] @ e[:3])
            vel_sq[k] += float(e[3:] @ e[3:])
            nees[k] += float(e @ np.linalg.solve(np.asarray(tr.estimate.covariance, dtype=np.float64), e))
            if tr.nis is not None:
                nis[k] += tr.nis
                n_nis[k] += 1
            n_matched[k] += 1
        if k == T - 1:
            final_matched = [i in cur for i in range(n_tgt)]
    return {
        "ospa_m": ospa_t,
        "ospa_mean_m": float(np.mean(ospa_t)) if ospa_t else 0.0,
        "gospa_m": [g["gospa"] for g in gospa_t],
        "gospa_localisation_m2": [g["localisation"] for g in gospa_t],
        "gospa_missed": [g["missed"] for g in gospa_t],
        "gospa_false": [g["false"] for g in gospa_t],
        "pos_sq_err_m2": pos_sq.tolist(),
        "vel_sq_err_m2s2": vel_sq.tolist(),
        "nees_sum": nees.tolist(),
        "nis_sum": nis.tolist(),
        "n_nis": n_nis.tolist(),
        "n_matched": n_matched.tolist(),
        "n_alive": n_alive.tolist(),
        "coverage": float(n_matched.sum() / max(n_alive.sum(), 1)),
        "id_switches": ident["id_switches"],
        "id_swaps": ident["id_swaps"],
        "id_restarts": ident["id_restarts"],
        "fragmentations": ident["fragmentations"],
        "breaks": ident["breaks"],
        "assignment_changes": changes,
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
    nees = np.sum([r["nees_sum"] for r in runs], axis=0)
    nis = np.sum([r["nis_sum"] for r in runs], axis=0)
    n_nis = np.sum([r["n_nis"] for r in runs], axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        pos_rmse = np.where(n > 0, np.sqrt(pos / np.maximum(n, 1)), np.nan)
        vel_rmse = np.where(n > 0, np.sqrt(vel / np.maximum(n, 1)), np.nan)
        mean_nees = np.where(n > 0, nees / np.maximum(n, 1), np.nan)
        mean_nis = np.where(n_nis > 0, nis / np.maximum(n_nis, 1), np.nan)
    ospa_t = np.mean([r["ospa_m"] for r in runs], axis=0)
    gospa_t = np.mean([r["gospa_m"] for r in runs], axis=0)
    finals = np.array([r["final_matched"] for r in runs], dtype=float)

    def per_run(key: str) -> float:
        return float(np.mean([r[key] for r in runs]))

    return {
        "n_runs": len(runs),
        "pos_rmse_m": [float(v) for v in pos_rmse],
        "vel_rmse_mps": [float(v) for v in vel_rmse],
        "nees_mean": [float(v) for v in mean_nees],
        "nis_mean": [float(v) for v in mean_nis],
        "ospa_mean_m_per_scan": [float(v) for v in ospa_t],
        "ospa_mean_m": float(np.mean(ospa_t)),
        "gospa_mean_m_per_scan": [float(v) for v in gospa_t],
        "gospa_mean_m": float(np.mean(gospa_t)),
        "gospa_missed_per_scan": float(np.mean([np.mean(r["gospa_missed"]) for r in runs])),
        "gospa_false_per_scan": float(np.mean([np.mean(r["gospa_false"]) for r in runs])),
        "coverage": per_run("coverage"),
        "id_switches_per_run": per_run("id_switches"),
        "id_swaps_per_run": per_run("id_swaps"),
        "id_restarts_per_run": per_run("id_restarts"),
        "fragmentations_per_run": per_run("fragmentations"),
        "breaks_per_run": per_run("breaks"),
        "assignment_changes_per_run": per_run("assignment_changes"),
        "false_confirmed_tracks_per_run": per_run("false_confirmed_tracks"),
        "final_track_fraction": float(finals.mean()) if finals.size else 0.0,
    }
