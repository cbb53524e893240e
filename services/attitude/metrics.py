"""Monte-Carlo metrics of the attitude estimator as plain dicts (§3.3, §4).

* :func:`run_record` turns one run (the estimates of one target and the matching truth) into a per-run dict of
  errors and reported sigmas per scan;
* :func:`aggregate` combines per-run dicts into per-scan RMS and mean errors (filtered and raw), the first scan
  at which the RMS drops below given thresholds, and the consistency of the reported sigmas (C1/C2).

The error of an angle is wrap(estimate - truth) into (-180, 180] deg; truth LOS angles use the true position
(§4.6). An undefined estimate (null) counts as missing and is reported in ``defined_fraction``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from schemas import Truth
from schemas.attitude import AttitudeEstimate

from .angles import attitude_angles
from .geometry import F64

#: angle name -> (estimate field, sigma field); raw angles use the estimate field name on ``raw``
ANGLE_FIELDS: dict[str, tuple[str, str | None]] = {
    "psi": ("psi_deg", "sigma_psi_deg"),
    "theta": ("theta_deg", "sigma_theta_deg"),
    "gamma": ("gamma_deg", "sigma_gamma_deg"),
    "psi_los": ("psi_los_deg", "sigma_psi_los_deg"),
    "theta_los": ("theta_los_deg", "sigma_theta_los_deg"),
    "gamma_los": ("gamma_los_deg", "sigma_gamma_los_deg"),
    "gamma_los_euler": ("gamma_los_euler_deg", "sigma_gamma_los_euler_deg"),
    "aspect_az": ("aspect_az_deg", "sigma_aspect_az_deg"),
    "aspect_el": ("aspect_el_deg", "sigma_aspect_el_deg"),
    "aspect_total": ("aspect_total_deg", "sigma_aspect_total_deg"),
}
LOS_ANGLES = ("psi_los", "theta_los", "gamma_los")


def truth_angles(truth: Truth, los_x: str = "radar_to_target", gamma_los_form: str = "paper") -> dict[str, float]:
    """True angles (deg) of a Truth message: its attitude [heading, pitch, roll] and LOS angles from the true
    position. ``gamma_los`` is in the requested form (paper or Euler), as the estimator reports it."""
    if truth.attitude_rad is None:
        raise ValueError("truth has no attitude")
    psi, theta, gamma = truth.attitude_rad
    p = truth.position_m
    beta = math.atan2(p[2], p[0])
    eps = math.atan2(p[1], math.hypot(p[0], p[2]))
    psi_l, th_l, g_l, g_e, q_az, q_el, q = (float(v) for v in attitude_angles(psi, theta, gamma, beta, eps, los_x))
    d = math.degrees
    return {
        "psi": d(psi) % 360.0,
        "theta": d(theta),
        "gamma": d(gamma),
        "psi_los": d(psi_l),
        "theta_los": d(th_l),
        "gamma_los": d(g_l) if gamma_los_form == "paper" else d(g_e),
        "gamma_los_euler": d(g_e),
        "aspect_az": d(q_az),
        "aspect_el": d(q_el),
        "aspect_total": d(q),
    }


def _err(est: float | None, true: float) -> float:
    """wrap(est - true) into (-180, 180] deg (scalar)."""
    if est is None:
        return math.nan
    d = (est - true + 180.0) % 360.0 - 180.0
    return 180.0 if d == -180.0 else d


class RunRecorder:
    """Builds the per-run record scan by scan, so a Monte-Carlo driver need not keep the estimates."""

    def __init__(self) -> None:
        self.rec: dict[str, Any] = {
            "stamp_ns": [],
            "status": [],
            "err": {n: [] for n in ANGLE_FIELDS},
            "sigma": {n: [] for n in ANGLE_FIELDS},
            "raw_err": {n: [] for n in ANGLE_FIELDS},
            "pos_err_m": [],
            "vel_err_mps": [],
        }

    def add(self, est: AttitudeEstimate | None, truth: Truth, true_angles: Mapping[str, float] | None = None) -> None:
        """Record the estimate (or None) that matches one truth sample; ``true_angles`` may be precomputed."""
        rec = self.rec
        rec["stamp_ns"].append(truth.header.stamp_ns)
        rec["status"].append(None if est is None else est.status)
        if est is None:
            for name in ANGLE_FIELDS:
                rec["err"][name].append(math.nan)
                rec["sigma"][name].append(math.nan)
                rec["raw_err"][name].append(math.nan)
            rec["pos_err_m"].append(math.nan)
            rec["vel_err_mps"].append(math.nan)
            return
        ta = true_angles if true_angles is not None else truth_angles(truth, est.los_x, est.gamma_los_form)
        raw = est.raw
        for name, (f_val, f_sig) in ANGLE_FIELDS.items():
            rec["err"][name].append(_err(getattr(est, f_val), ta[name]))
            sig = getattr(est, f_sig) if f_sig is not None else None
            rec["sigma"][name].append(math.nan if sig is None else float(sig))
            rec["raw_err"][name].append(math.nan if raw is None else _err(getattr(raw, f_val), ta[name]))
        x = est.state
        if x is None:
            rec["pos_err_m"].append(math.nan)
            rec["vel_err_mps"].append(math.nan)
            return
        p, v = truth.position_m, truth.velocity_mps
        rec["pos_err_m"].append(math.sqrt((x[0] - p[0]) ** 2 + (x[3] - p[1]) ** 2 + (x[6] - p[2]) ** 2))
        rec["vel_err_mps"].append(
            math.nan if v is None else math.sqrt((x[1] - v[0]) ** 2 + (x[4] - v[1]) ** 2 + (x[7] - v[2]) ** 2)
        )


def run_record(estimates: Sequence[AttitudeEstimate], truths: Sequence[Truth]) -> dict[str, Any]:
    """Per-run metrics: for each truth stamp, the errors (deg) and reported sigmas (deg) of the estimate with
    the same stamp (NaN where there is none or the angle is undefined), raw-baseline errors, position and
    velocity error norms (m, m/s) and the status word. Plain lists, JSON-friendly."""
    by_stamp = {e.header.stamp_ns: e for e in estimates if e.status != "COASTING"}
    recorder = RunRecorder()
    for tr in truths:
        recorder.add(by_stamp.get(tr.header.stamp_ns), tr)
    return recorder.rec


def _nanmean(a: F64) -> F64:
    """Mean over runs (axis 0) ignoring NaN; NaN where no run has a value."""
    ok = np.isfinite(a)
    n = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.where(ok, a, 0.0).sum(axis=0) / n, np.nan)


def _rms(a: F64) -> F64:
    return np.sqrt(_nanmean(a * a))


def first_scan_below(rms: Sequence[float], threshold: float, first_scan: int = 1) -> int | None:
    """First scan number (1-based by default) at which the RMS is below the threshold, or None."""
    for k, v in enumerate(rms):
        if math.isfinite(v) and v < threshold:
            return k + first_scan
    return None


def aggregate(
    records: Sequence[Mapping[str, Any]],
    thresholds_deg: Sequence[float] = (5.0, 3.0),
    consistency_scans: tuple[int, int] = (21, 100),
) -> dict[str, Any]:
    """Combine per-run records (equal length, scan-aligned) into per-scan statistics (lists indexed by scan-1).

    Keys: ``rms``, ``mean``, ``raw_rms``, ``raw_mean``, ``sigma_rms`` (sqrt of the mean reported variance),
    ``defined_fraction`` per angle; ``pos_rms_m``, ``vel_rms_mps``; ``first_scan_below`` per threshold and
    angle; ``consistency``: per angle, the ratio sigma_rms / rms for each scan of ``consistency_scans`` and its
    mean (C1: ~1 for a matched model; C2: >= 0.95 for a conservative filter).
    """
    n_runs = len(records)
    out: dict[str, Any] = {"n_runs": n_runs, "n_scans": len(records[0]["stamp_ns"]) if records else 0}
    for key, src in (("rms", "err"), ("raw_rms", "raw_err")):
        out[key] = {}
        out[key.replace("rms", "mean")] = {}
        for name in ANGLE_FIELDS:
            a = np.array([r[src][name] for r in records], dtype=np.float64)
            out[key][name] = _rms(a).tolist()
            out[key.replace("rms", "mean")][name] = _nanmean(a).tolist()
    out["sigma_rms"] = {}
    out["defined_fraction"] = {}
    for name in ANGLE_FIELDS:
        s = np.array([r["sigma"][name] for r in records], dtype=np.float64)
        e = np.array([r["err"][name] for r in records], dtype=np.float64)
        out["sigma_rms"][name] = _rms(s).tolist()
        out["defined_fraction"][name] = np.mean(np.isfinite(e), axis=0).tolist()
    out["pos_rms_m"] = _rms(np.array([r["pos_err_m"] for r in records], dtype=np.float64)).tolist()
    out["vel_rms_mps"] = _rms(np.array([r["vel_err_mps"] for r in records], dtype=np.float64)).tolist()
    out["first_scan_below"] = {
        f"{thr:g}": {name: first_scan_below(out["rms"][name], thr) for name in ANGLE_FIELDS} for thr in thresholds_deg
    }
    k0, k1 = consistency_scans
    cons: dict[str, Any] = {}
    for name in ANGLE_FIELDS:
        rms = np.asarray(out["rms"][name][k0 - 1 : k1])
        sig = np.asarray(out["sigma_rms"][name][k0 - 1 : k1])
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = sig / rms
        cons[name] = {"scans": [k0, k1], "ratio": ratio.tolist(), "mean_ratio": float(np.nanmean(ratio))}
    out["consistency"] = cons
    return out
