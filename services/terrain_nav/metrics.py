"""Per-run and aggregate Monte-Carlo metrics as plain dicts (digest §4 scoring).

* The truth of a fix is the true (drifting) offset at t_fix (the fix's stamp); the error in cells is
  ``(dx_hat - dx_true, dz_hat - dz_true)/cell``. A **false fix** is an issued fix more than 1 cell off on
  either axis (the paper's accuracy figure).
* Availability: a valid fix within ``availability_s`` of the start of the flight (N_max cell crossings).
* "Which condition blocked": verdict states, and per condition how often it was false once C1 held.
* Vertical channel: |dh_hat - dh_true| against 3 sqrt(P_hh), and its size once N_valid >= N_max.
"""

from __future__ import annotations

import bisect
import math
from collections import Counter
from collections.abc import Iterable, Sequence
from typing import Any, Protocol

import numpy as np

from schemas import Message, Truth
from schemas.terrain_nav import TerrainFix, TerrainVerdict

STATUS_STATES = ("OUT_OF_ZONE", "GAP", "RESET")


class TruthSource(Protocol):
    """What scoring needs: the true corrections at a time, the start time and the cell size."""

    @property
    def t0_s(self) -> float: ...

    @property
    def cell_m(self) -> float: ...

    def truth_at(self, t: float) -> dict[str, float]: ...


class TruthTrack:
    """A :class:`TruthSource` from the simulator's ``Truth`` messages (``extra`` dx_m, dz_m, dh_m, dV_mps).

    Linear interpolation between the messages, so a scenario player's truth stream can be scored too.
    """

    def __init__(self, truths: Iterable[Truth], cell_m: float) -> None:
        rows = sorted((m.header.stamp_ns * 1e-9, m.extra) for m in truths)
        if not rows:
            raise ValueError("no Truth message")
        self._t = [r[0] for r in rows]
        self._x = [r[1] for r in rows]
        self._t0 = self._t[0]
        self._cell = cell_m

    @property
    def t0_s(self) -> float:
        return self._t0

    @property
    def cell_m(self) -> float:
        return self._cell

    def truth_at(self, t: float) -> dict[str, float]:
        k = min(max(bisect.bisect_right(self._t, t), 1), len(self._t) - 1) if len(self._t) > 1 else 0
        if len(self._t) == 1:
            e = self._x[0]
            return {"dx": e["dx_m"], "dz": e["dz_m"], "dh": e["dh_m"], "dV": e["dV_mps"]}
        t0, t1 = self._t[k - 1], self._t[k]
        w = (t - t0) / (t1 - t0)
        a, b = self._x[k - 1], self._x[k]
        return {key: a[name] + w * (b[name] - a[name]) for key, name in
                (("dx", "dx_m"), ("dz", "dz_m"), ("dh", "dh_m"), ("dV", "dV_mps"))}  # fmt: skip


def fix_errors_cells(fix: TerrainFix, truth: TruthSource) -> tuple[float, float]:
    """Horizontal error of one fix in cells (longitudinal, transverse)."""
    d = truth.truth_at(fix.header.stamp_ns * 1e-9)
    cell = truth.cell_m
    return (fix.dx_m - d["dx"]) / cell, (fix.dz_m - d["dz"]) / cell


def score_run(outputs: Iterable[Message], flight: TruthSource, availability_s: float = 40.0) -> dict[str, Any]:
    """Metrics of one run from its output messages and the truth (a simulated flight or a TruthTrack)."""
    t0 = flight.t0_s
    verdicts = [m for m in outputs if isinstance(m, TerrainVerdict)]
    fixes = [m for m in outputs if isinstance(m, TerrainFix)]
    errs = [fix_errors_cells(f, flight) for f in fixes]
    abs_max = [max(abs(ex), abs(ez)) for ex, ez in errs]
    states = Counter(v.state for v in verdicts)
    evals = [v for v in verdicts if v.state not in STATUS_STATES]
    after_c1 = [v for v in evals if v.c1_enough_data]
    vert_err, vert_ratio_ok, vert_err_full = [], [], []
    for f in fixes:
        truth = flight.truth_at(f.header.stamp_ns * 1e-9)
        dh = f.vertical.index("dh")
        e = abs(f.vertical.mean[dh] - truth["dh"])
        vert_err.append(e)
        vert_ratio_ok.append(e <= 3.0 * math.sqrt(f.vertical.covariance[dh][dh]))
        if f.verdict.n_valid >= f.verdict.n_max:
            vert_err_full.append(e)
    first = fixes[0] if fixes else None
    first_s = first.header.stamp_ns * 1e-9 - t0 if first is not None else None
    return {
        "n_verdicts": len(evals),
        "n_fixes": len(fixes),
        "errors_cells": errs,
        "max_abs_error_cells": max(abs_max) if abs_max else None,
        "n_false_fixes": sum(a > 1.0 for a in abs_max),
        "n_over_1_5_cells": sum(a > 1.5 for a in abs_max),
        "first_fix_s": first_s,
        "first_fix_error_cells": errs[0] if errs else None,
        "available": first_s is not None and first_s <= availability_s,
        "states": dict(states),
        "n_after_c1": len(after_c1),
        "c2_false_after_c1": sum(not v.c2_fit for v in after_c1),
        "c3_false_after_c1": sum(not v.c3_unique for v in after_c1),
        "c4_false_after_c1": sum(not v.c4_stable for v in after_c1),
        "vertical_abs_error_m": vert_err,
        "vertical_within_3sigma": vert_ratio_ok,
        "vertical_abs_error_full_window_m": vert_err_full,
    }


def _pct(values: Sequence[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if len(values) else None


def aggregate(runs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Aggregate per-run metrics over a Monte-Carlo set."""
    n = len(runs)
    firsts = [r["first_fix_s"] for r in runs if r["first_fix_s"] is not None]
    n_fix = sum(r["n_fixes"] for r in runs)
    all_abs = [max(abs(ex), abs(ez)) for r in runs for ex, ez in r["errors_cells"]]
    n_after_c1 = sum(r["n_after_c1"] for r in runs)
    vert = [e for r in runs for e in r["vertical_abs_error_m"]]
    vert_ok = [ok for r in runs for ok in r["vertical_within_3sigma"]]
    vert_full = [e for r in runs for e in r["vertical_abs_error_full_window_m"]]
    states: Counter[str] = Counter()
    for r in runs:
        states.update(r["states"])
    return {
        "runs": n,
        "availability": sum(r["available"] for r in runs) / n if n else None,
        "runs_with_fix": sum(r["n_fixes"] > 0 for r in runs),
        "first_fix_s_median": _pct(firsts, 50),
        "first_fix_s_p90": _pct(firsts, 90),
        "first_fix_s_max": max(firsts) if firsts else None,
        "fixes": n_fix,
        "fixes_within_1_cell": (sum(a <= 1.0 for a in all_abs) / n_fix) if n_fix else None,
        "false_fixes": sum(r["n_false_fixes"] for r in runs),
        "false_fix_rate": (sum(r["n_false_fixes"] for r in runs) / n_fix) if n_fix else 0.0,
        "runs_with_false_fix": sum(r["n_false_fixes"] > 0 for r in runs),
        "fixes_over_1_5_cells": sum(r["n_over_1_5_cells"] for r in runs),
        "max_abs_error_cells": max(all_abs) if all_abs else None,
        "states": dict(states),
        "evaluations_after_c1": n_after_c1,
        "c2_false_after_c1": (sum(r["c2_false_after_c1"] for r in runs) / n_after_c1) if n_after_c1 else None,
        "c3_false_after_c1": (sum(r["c3_false_after_c1"] for r in runs) / n_after_c1) if n_after_c1 else None,
        "c4_false_after_c1": (sum(r["c4_false_after_c1"] for r in runs) / n_after_c1) if n_after_c1 else None,
        "vertical_within_3sigma": (sum(vert_ok) / len(vert_ok)) if vert_ok else None,
        "vertical_abs_error_median_m": _pct(vert, 50),
        "vertical_full_window_median_m": _pct(vert_full, 50),
        "vertical_full_window_p95_m": _pct(vert_full, 95),
    }
