"""Per-run and aggregate Monte-Carlo metrics of the LBL estimator, as plain dicts (digest 000, section 3.1).

* eta(t): share of runs with an unambiguous solution (decision or merge) by t - t_0 (Fig. 5g);
* wrong decisions (rule (6) accepted the mirror hypothesis);
* resolution-time distribution (median and 90th percentile; runs never resolved count as +inf);
* actual RMS (over realisations) and computed RMS (from the filter covariance) of x and y over the runs whose
  solution is unambiguous and correct at t (Fig. 5b, 5v).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .offline import RunTrace


def _at(tr: RunTrace, t: float) -> int | None:
    if tr.t_s.size == 0:
        return None
    dt = float(tr.t_s[1] - tr.t_s[0]) if tr.t_s.size > 1 else 1.0
    j = round(float((t - tr.t_s[0]) / dt))
    return j if 0 <= j < tr.t_s.size else None


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def run_metrics(tr: RunTrace, t_grid: Sequence[float]) -> dict[str, Any]:
    """Plain-dict summary of one run: resolution, correctness and, per t of ``t_grid``, the position error and
    filter sigma of the single-hypothesis fix (None while ambiguous or after the trace ended)."""
    err_x: list[float | None] = []
    err_y: list[float | None] = []
    sd_x: list[float | None] = []
    sd_y: list[float | None] = []
    for t in t_grid:
        j = _at(tr, t)
        if j is None or not np.isfinite(tr.pos[j, 0]):
            err_x.append(None)
            err_y.append(None)
            sd_x.append(None)
            sd_y.append(None)
            continue
        e = tr.pos[j] - tr.truth[j]
        err_x.append(_num(e[0]))
        err_y.append(_num(e[1]))
        sd_x.append(_num(math.sqrt(tr.var[j, 0])))
        sd_y.append(_num(math.sqrt(tr.var[j, 1])))
    return {
        "seed": tr.seed,
        "launched": tr.launched,
        "resolution_t_s": tr.resolution_t_s,
        "merged": tr.merged,
        "decided": tr.decided,
        "true_label": tr.true_label,
        "wrong": tr.wrong,
        "rejected_inputs": tr.rejected_inputs,
        "t_s": [float(t) for t in t_grid],
        "err_x": err_x,
        "err_y": err_y,
        "sd_x": sd_x,
        "sd_y": sd_y,
    }


def _quantile_inf(values: Sequence[float], q: float) -> float:
    """Quantile where unresolved runs count as +inf (returns inf when the quantile falls on them)."""
    v = np.sort(np.asarray(values, dtype=float))
    if v.size == 0:
        return math.inf
    k = q * (v.size - 1)
    lo, hi = math.floor(k), math.ceil(k)
    if not (math.isfinite(v[lo]) and math.isfinite(v[hi])):
        return math.inf
    return float(v[lo] + (v[hi] - v[lo]) * (k - lo))


def _unambiguous(r: dict[str, Any], t: float) -> bool:
    return r["resolution_t_s"] is not None and r["resolution_t_s"] <= t


def resolution_stats(per_run: Sequence[dict[str, Any]], horizon_s: float = math.inf) -> dict[str, Any]:
    """Resolution time after launch: share resolved within the horizon, median and p90 (unresolved = inf)."""
    times = [
        r["resolution_t_s"] if r["resolution_t_s"] is not None and r["resolution_t_s"] <= horizon_s else math.inf
        for r in per_run
    ]
    finite = [t for t in times if math.isfinite(t)]
    return {
        "runs": len(per_run),
        "resolved": len(finite),
        "resolved_share": len(finite) / len(per_run) if per_run else 0.0,
        "wrong": sum(bool(r["wrong"]) for r in per_run),
        "merged": sum(bool(r["merged"]) for r in per_run),
        "median_s": _quantile_inf(times, 0.5),
        "p90_s": _quantile_inf(times, 0.9),
        "median_resolved_s": float(np.median(finite)) if finite else None,
        "times_s": times,
    }


def eta_curve(per_run: Sequence[dict[str, Any]], t_grid: Sequence[float]) -> dict[str, list[float]]:
    """eta(t) (unambiguous share), the correct share and the cumulative wrong decisions at each t."""
    n = max(len(per_run), 1)
    return {
        "t_s": [float(t) for t in t_grid],
        "eta": [sum(_unambiguous(r, t) for r in per_run) / n for t in t_grid],
        "eta_correct": [sum(_unambiguous(r, t) and not r["wrong"] for r in per_run) / n for t in t_grid],
        "wrong": [float(sum(_unambiguous(r, t) and bool(r["wrong"]) for r in per_run)) for t in t_grid],
    }


def rms_curves(per_run: Sequence[dict[str, Any]]) -> dict[str, list[float | None]]:
    """Actual and computed RMS of x and y (m) over runs with a correct unambiguous solution at each t of the
    runs' common grid."""
    keys = ("n", "actual_x", "actual_y", "computed_x", "computed_y", "actual_h", "computed_h")
    out: dict[str, list[float | None]] = {k: [] for k in keys}
    if not per_run:
        return out
    t_grid = per_run[0]["t_s"]
    for j, t in enumerate(t_grid):
        rows = [
            (r["err_x"][j], r["err_y"][j], r["sd_x"][j], r["sd_y"][j])
            for r in per_run
            if _unambiguous(r, t) and not r["wrong"] and r["err_x"][j] is not None
        ]
        out["n"].append(float(len(rows)))
        if not rows:
            for k in keys[1:]:
                out[k].append(None)
            continue
        a = np.array(rows, dtype=float)
        ax, ay = np.sqrt(np.mean(a[:, :2] ** 2, axis=0))
        cx, cy = np.sqrt(np.mean(a[:, 2:] ** 2, axis=0))
        out["actual_x"].append(float(ax))
        out["actual_y"].append(float(ay))
        out["computed_x"].append(float(cx))
        out["computed_y"].append(float(cy))
        out["actual_h"].append(float(math.hypot(ax, ay)))
        out["computed_h"].append(float(math.hypot(cx, cy)))
    return out


def aggregate_runs(per_run: Sequence[dict[str, Any]], horizon_s: float | None = None) -> dict[str, Any]:
    """Everything above for one Monte-Carlo set of ``run_metrics`` dicts (same t grid), JSON-able."""
    t_grid = per_run[0]["t_s"] if per_run else []
    horizon = (max(t_grid) if t_grid else math.inf) if horizon_s is None else horizon_s
    return {
        "resolution": resolution_stats(per_run, horizon),
        "eta": eta_curve(per_run, t_grid),
        "rms": rms_curves(per_run),
        "launched": sum(bool(r["launched"]) for r in per_run),
        "rejected_inputs": sum(int(r.get("rejected_inputs", 0)) for r in per_run),
    }


def aggregate(traces: Sequence[RunTrace], t_grid: Sequence[float], horizon_s: float | None = None) -> dict[str, Any]:
    """``aggregate_runs`` of the traces' ``run_metrics`` on ``t_grid``."""
    return aggregate_runs([run_metrics(tr, t_grid) for tr in traces], horizon_s)


def binomial_upper95(k: int, n: int) -> float:
    """One-sided 95 % Clopper-Pearson upper bound of a rate observed k times in n trials (1 if k >= n)."""
    from scipy.stats import beta

    if n <= 0 or k >= n:
        return 1.0
    return float(beta.ppf(0.95, k + 1, n - k))
