"""Per-run and Monte-Carlo metrics of digest 002 §5.4/§6 as plain dicts (JSON-able).

Per-axis statistics are of the signed north (x) and east (y) errors at the leader-arrival epoch of every
cycle; |e| is the horizontal error. The consistency ratio is RMS(|e|) / RMS(sqrt(trace Q_k)).
Per-run dicts carry sums (so pooling over runs is exact) and the |e| samples (for pooled percentiles).
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np

from .geometry import F64

#: columns of a cycle-fix record (one row per CYCLE fix)
COLUMNS = ("t_s", "x_m", "y_m", "qxx", "qxy", "qyy", "tx_m", "ty_m")


def _arr(rows: list[tuple[float, ...]]) -> F64:
    return np.asarray(rows, dtype=np.float64).reshape(-1, len(COLUMNS))


def error_stats(rows: list[tuple[float, ...]]) -> dict[str, Any]:
    """Sums and samples of the errors of one estimator over one run."""
    a = _arr(rows)
    ex = a[:, 1] - a[:, 6]
    ey = a[:, 2] - a[:, 7]
    e2 = ex * ex + ey * ey
    tr = a[:, 3] + a[:, 5]
    det = a[:, 3] * a[:, 5] - a[:, 4] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        nees = (a[:, 5] * ex * ex - 2 * a[:, 4] * ex * ey + a[:, 3] * ey * ey) / det
    n = int(a.shape[0])
    abs_e = np.sqrt(e2)
    return {
        "n": n,
        "sum_ex": float(ex.sum()),
        "sum_ey": float(ey.sum()),
        "sum_ex2": float((ex * ex).sum()),
        "sum_ey2": float((ey * ey).sum()),
        "sum_e2": float(e2.sum()),
        "sum_trq": float(tr.sum()),
        "sum_nees": float(np.nansum(nees)),
        "abs_err_m": abs_e.tolist(),
        "max_abs_m": float(abs_e.max()) if n else math.nan,
        "rms_m": float(math.sqrt(e2.mean())) if n else math.nan,
        "p99_m": float(np.percentile(abs_e, 99)) if n else math.nan,
        "ex_m": ex.tolist(),
        "ey_m": ey.tolist(),
    }


def summarize(stats: list[dict[str, Any]]) -> dict[str, Any]:
    """Pooled figures over the error stats of several runs (or one)."""
    n = sum(s["n"] for s in stats)
    if n == 0:
        return {"n": 0}
    sx = sum(s["sum_ex"] for s in stats)
    sy = sum(s["sum_ey"] for s in stats)
    sxx = sum(s["sum_ex2"] for s in stats)
    syy = sum(s["sum_ey2"] for s in stats)
    se2 = sum(s["sum_e2"] for s in stats)
    strq = sum(s["sum_trq"] for s in stats)
    snees = sum(s["sum_nees"] for s in stats)
    abs_e = np.concatenate([np.asarray(s["abs_err_m"]) for s in stats])
    mean_x, mean_y = sx / n, sy / n
    return {
        "n": n,
        "runs": len(stats),
        "mean_x_m": mean_x,
        "mean_y_m": mean_y,
        "sd_x_m": math.sqrt(max(sxx / n - mean_x**2, 0.0)),
        "sd_y_m": math.sqrt(max(syy / n - mean_y**2, 0.0)),
        "rms_m": math.sqrt(se2 / n),
        "p99_m": float(np.percentile(abs_e, 99)),
        "p999_m": float(np.percentile(abs_e, 99.9)),
        "max_m": float(abs_e.max()),
        "consistency": math.sqrt(se2 / n) / math.sqrt(strq / n) if strq > 0 else math.nan,
        "mean_nees": snees / n,
        "frac_runs_max_le_2m": float(np.mean([s["max_abs_m"] <= 2.0 for s in stats])),
        "max_run_rms_m": max(s["rms_m"] for s in stats),
    }


def run_metrics(
    pf_rows: list[tuple[float, ...]],
    ekf_rows: list[tuple[float, ...]],
    reinit_count: int,
    rejected_cycles: Counter[str] | dict[str, int],
    rejected_inputs: Counter[str] | dict[str, int],
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Metrics of one run: PF and EKF error stats, re-initialisations, rejections by reason."""
    pf = error_stats(pf_rows)
    ekf = error_stats(ekf_rows) if ekf_rows else None
    out: dict[str, Any] = {
        "pf": pf,
        "pf_summary": summarize([pf]),
        "ekf": ekf,
        "ekf_summary": summarize([ekf]) if ekf is not None else None,
        "reinit_count": int(reinit_count),
        "rejected_cycles": dict(rejected_cycles),
        "rejected_inputs": dict(rejected_inputs),
    }
    if extra:
        out.update(extra)
    return out


def aggregate(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Monte-Carlo aggregate over per-run dicts of :func:`run_metrics`."""
    cyc: Counter[str] = Counter()
    inp: Counter[str] = Counter()
    for r in runs:
        cyc.update(r["rejected_cycles"])
        inp.update(r["rejected_inputs"])
    ekf = [r["ekf"] for r in runs if r.get("ekf")]
    return {
        "runs": len(runs),
        "pf": summarize([r["pf"] for r in runs]),
        "ekf": summarize(ekf) if ekf else None,
        "reinit_total": sum(r["reinit_count"] for r in runs),
        "reinit_per_run": [r["reinit_count"] for r in runs],
        "rejected_cycles": dict(cyc),
        "rejected_inputs": dict(inp),
    }
