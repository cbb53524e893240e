"""NEES consistency of the cycle fixes by motion regime, and its chi-square bands over Monte-Carlo runs.

A consistent 2-D estimator's NEES e^T Q^-1 e is chi-square with 2 degrees of freedom: mean 2. Over N independent
runs the average NEES at one epoch (ANEES, Bar-Shalom, Li & Kirubarajan 2001, §5.4) is chi2_{2N} / N, so its
two-sided 95 % band is [chi2_{2N}(0.025) / N, chi2_{2N}(0.975) / N] (N = 40: [1.43, 2.67]). Reported per regime:

* ``anees``: the average over the run-epochs of a regime (each epoch the mean over the runs that have it); it must lie
  in the band of N runs (time averaging only narrows its spread, so this band is the lenient one);
* ``in_band``: the fraction of epochs whose ANEES lies in its own band (n_k runs): about 95 % if consistent.

Regimes, from the truth at each fix's epoch (``Truth.velocity_mps``): ``hover`` (speed < ``hover_mps``),
``manoeuvre`` (the heading changes by more than ``turn_deg`` or the speed by more than ``speed_change_mps`` within
``window_s`` either side: turns, stops, starts, speed steps) and ``straight`` (the rest).
"""

from __future__ import annotations

import math
from collections import defaultdict
from typing import Any

import numpy as np
from scipy.stats import chi2

from schemas import Truth
from shared.truth import linear_at

from .geometry import F64

REGIMES = ("straight", "manoeuvre", "hover")


def band(n_runs: int, dof: int = 2, p: float = 0.95) -> tuple[float, float]:
    """Two-sided band of the average NEES over n_runs independent runs."""
    a = 0.5 * (1.0 - p)
    return float(chi2.ppf(a, dof * n_runs) / n_runs), float(chi2.ppf(1.0 - a, dof * n_runs) / n_runs)


class Regimes:
    """Classifies stamps by the truth's speed and heading history."""

    def __init__(
        self,
        truths: list[Truth],
        window_s: float = 30.0,
        hover_mps: float = 0.01,
        turn_deg: float = 5.0,
        speed_change_mps: float = 0.05,
    ) -> None:
        rows = sorted((m.header.stamp_ns, m.velocity_mps[0], m.velocity_mps[1]) for m in truths if m.velocity_mps)
        t = np.array([r[0] for r in rows], dtype=np.float64)
        v = np.array([r[1:] for r in rows], dtype=np.float64).reshape(-1, 2)
        keep = np.concatenate([[True], np.diff(t) > 0]) if t.size else np.zeros(0, dtype=bool)
        self.t, self.v = t[keep], v[keep]
        self.window_ns = window_s * 1e9
        self.hover = hover_mps
        self.turn = math.radians(turn_deg)
        self.dspeed = speed_change_mps

    def of(self, stamps_ns: list[int]) -> list[str]:
        if self.t.size == 0:
            return ["straight"] * len(stamps_ns)
        s = np.asarray(stamps_ns, dtype=np.float64)
        out = []
        for k, st in enumerate(s):
            v0 = linear_at(self.t, self.v, [st])[0]
            speed = float(np.hypot(*v0)) if np.isfinite(v0).all() else math.nan
            if speed < self.hover:
                out.append("hover")
                continue
            lo, hi = np.searchsorted(self.t, [st - self.window_ns, st + self.window_ns])
            vs = self.v[max(lo - 1, 0) : hi + 1]
            sp = np.hypot(vs[:, 0], vs[:, 1])
            moving = vs[sp >= self.hover]
            h = np.arctan2(moving[:, 0], moving[:, 1]) if moving.size else np.zeros(0)
            dh = np.abs(np.angle(np.exp(1j * (h - math.atan2(v0[0], v0[1]))))) if h.size else np.zeros(1)
            turning = bool(np.max(dh) > self.turn)
            speeding = bool(np.max(np.abs(sp - speed)) > self.dspeed) if sp.size else False
            out.append("manoeuvre" if turning or speeding else "straight")
            del k
        return out


def nees(rows: list[tuple[float, ...]]) -> F64:
    """NEES of metrics.COLUMNS rows (t, x, y, qxx, qxy, qyy, tx, ty)."""
    a = np.asarray(rows, dtype=np.float64).reshape(-1, 8)
    ex, ey = a[:, 1] - a[:, 6], a[:, 2] - a[:, 7]
    det = a[:, 3] * a[:, 5] - a[:, 4] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray((a[:, 5] * ex * ex - 2 * a[:, 4] * ex * ey + a[:, 3] * ey * ey) / det)


def per_run(rows: list[tuple[float, ...]], regimes: list[str], period_s: float) -> dict[str, Any]:
    """A run's NEES by epoch (cycle index round(t / period)) and regime, and its errors by regime."""
    n = nees(rows)
    a = np.asarray(rows, dtype=np.float64).reshape(-1, 8)
    e2 = (a[:, 1] - a[:, 6]) ** 2 + (a[:, 2] - a[:, 7]) ** 2
    out: dict[str, Any] = {"epochs": [], "by_regime": {}}
    for i, reg in enumerate(regimes):
        if math.isfinite(float(n[i])):
            out["epochs"].append([round(float(a[i, 0]) / period_s), float(n[i]), reg])
    for reg in REGIMES:
        m = np.array([r == reg for r in regimes], dtype=bool)
        if m.any():
            out["by_regime"][reg] = {
                "n": int(m.sum()),
                "sum_nees": float(np.nansum(n[m])),
                "sum_e2": float(e2[m].sum()),
                "sum_trq": float((a[m, 3] + a[m, 5]).sum()),
                "max_m": float(np.sqrt(e2[m].max())),
            }
    return out


def aggregate(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Pooled NEES, RMS and consistency ratio per regime, ANEES and its 95 % bands over the runs."""
    n_runs = len(runs)
    out: dict[str, Any] = {"runs": n_runs, "band_n_runs": band(n_runs) if n_runs else None}
    for reg in REGIMES:
        parts = [r["by_regime"][reg] for r in runs if reg in r["by_regime"]]
        if not parts:
            continue
        n = sum(p["n"] for p in parts)
        by_epoch: dict[int, list[float]] = defaultdict(list)
        for r in runs:
            for k, v, g in r["epochs"]:
                if g == reg:
                    by_epoch[int(k)].append(float(v))
        anees = [float(np.mean(v)) for v in by_epoch.values()]
        inside = [band(len(v))[0] <= float(np.mean(v)) <= band(len(v))[1] for v in by_epoch.values()]
        mean_anees = float(np.mean(anees)) if anees else math.nan
        lo, hi = band(n_runs)
        out[reg] = {
            "n": n,
            "mean_nees": sum(p["sum_nees"] for p in parts) / n,
            "rms_m": math.sqrt(sum(p["sum_e2"] for p in parts) / n),
            "consistency": math.sqrt(sum(p["sum_e2"] for p in parts) / sum(p["sum_trq"] for p in parts)),
            "max_m": max(p["max_m"] for p in parts),
            "epochs": len(anees),
            "anees": mean_anees,
            "anees_in_band": lo <= mean_anees <= hi,
            "in_band": float(np.mean(inside)) if inside else math.nan,
        }
    return out
