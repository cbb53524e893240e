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
import numpy.typing as npt
from scipy.stats import chi2

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


def truth_phase(truth: Truth) -> str | None:
    """The commanded flight phase of a truth sample (the ``attitude`` simulator's ``extra``): ``turn`` (commanded
    roll above 5 deg), ``manoeuvre`` (another commanded acceleration: pull-up, push-over, zero-g arc, climb entry),
    ``straight`` (none); None when the truth does not say."""
    extra = truth.extra
    if "manoeuvre" not in extra:
        return None
    if extra.get("turn", 0.0) > 0.5:
        return "turn"
    return "manoeuvre" if extra["manoeuvre"] > 0.5 else "straight"


def true_load_factor(truth: Truth, g: float = 9.81) -> float:
    """Normal load factor n = |f - (f.i) i| / g of the true motion, f = a + (0, g, 0) (frame E, y up); NaN
    without velocity or acceleration. Roll is undefined where n is near 0 (a zero-g arc)."""
    v, a = truth.velocity_mps, truth.acceleration_mps2
    if v is None or a is None:
        return math.nan
    speed = math.sqrt(sum(c * c for c in v))
    if speed == 0.0:
        return math.nan
    i = [c / speed for c in v]
    f = [a[0], a[1] + g, a[2]]
    fi = sum(fc * ic for fc, ic in zip(f, i, strict=True))
    return math.sqrt(sum((fc - fi * ic) ** 2 for fc, ic in zip(f, i, strict=True))) / g


def state_nees(est: AttitudeEstimate, truth: Truth) -> float:
    """NEES e^T P^-1 e of the 9-state [x Vx ax y Vy ay z Vz az] against the truth (frame E); NaN without a
    covariance, a true velocity or acceleration. chi2 with 9 degrees of freedom for a consistent filter."""
    if est.estimate is None or truth.velocity_mps is None or truth.acceleration_mps2 is None:
        return math.nan
    p, v, a = truth.position_m, truth.velocity_mps, truth.acceleration_mps2
    xt = np.array([p[0], v[0], a[0], p[1], v[1], a[1], p[2], v[2], a[2]])
    e = np.asarray(est.estimate.mean) - xt
    try:
        return float(e @ np.linalg.solve(np.asarray(est.estimate.covariance), e))
    except np.linalg.LinAlgError:
        return math.nan


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
            "nees": [],
            "phase": [],
            "since_manoeuvre_s": [],
            "load_factor_true": [],
        }

    def add(self, est: AttitudeEstimate | None, truth: Truth, true_angles: Mapping[str, float] | None = None) -> None:
        """Record the estimate (or None) that matches one truth sample; ``true_angles`` may be precomputed."""
        rec = self.rec
        rec["stamp_ns"].append(truth.header.stamp_ns)
        rec["status"].append(None if est is None else est.status)
        rec["phase"].append(truth_phase(truth))
        rec["since_manoeuvre_s"].append(truth.extra.get("since_manoeuvre_s", math.nan))
        rec["load_factor_true"].append(true_load_factor(truth))
        if est is None or est.estimate is None:
            rec["nees"].append(math.nan)
        else:
            rec["nees"].append(state_nees(est, truth))
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
        x = None if est.estimate is None else est.estimate.mean
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
        # all NaN (a run too short for these scans): NaN, without numpy's "mean of empty slice" warning on stderr
        mean = float(np.nanmean(ratio)) if np.any(~np.isnan(ratio)) else math.nan
        cons[name] = {"scans": [k0, k1], "ratio": ratio.tolist(), "mean_ratio": mean}
    out["consistency"] = cons
    return out


# ------------------------------------------------------------------------------------------------ flight phases
#: the classes of :func:`phase_samples`: the commanded phase of the truth, and ``steady`` = straight legs more
#: than STEADY_AFTER_S after the last commanded manoeuvre
PHASES = ("turn", "manoeuvre", "straight", "steady")
STEADY_AFTER_S = 30.0
#: angles scored per phase; roll-type angles only where the true normal load factor is at least MIN_LOAD_ROLL
PHASE_ANGLES = ("psi", "theta", "gamma", "psi_los", "theta_los", "gamma_los")
ROLL_ANGLES = frozenset({"gamma", "gamma_los"})
MIN_LOAD_ROLL = 0.3
NEES_DOF = 9


def _phase_masks(rec: Mapping[str, Any], first_scan: int) -> dict[str, npt.NDArray[np.bool_]]:
    phase = rec["phase"]
    since = np.asarray(rec["since_manoeuvre_s"], dtype=np.float64)
    k = np.arange(len(phase))
    settled = k >= first_scan - 1
    out = {name: np.array([p == name for p in phase]) & settled for name in ("turn", "manoeuvre", "straight")}
    out["steady"] = out["straight"] & (since > STEADY_AFTER_S)
    return out


def phase_samples(records: Sequence[Mapping[str, Any]], first_scan: int = 20) -> dict[str, dict[str, Any]]:
    """Sums over the runs of ONE target (records on the same scan grid) per flight phase, from scan
    ``first_scan`` on (after the start transient), for :func:`phase_table` to pool over targets:

    * ``n``, and per angle ``sq`` (sum of squared errors, deg^2) and ``count`` (defined estimates);
    * ``anees``: per scan of the phase, (mean NEES over the runs, runs with a NEES) -- the textbook ANEES;
    * ``nees_sum``, ``nees_n``, ``nees_in``: the per-sample NEES sum, count and count inside the chi2(9) 95 %
      interval;
    * ``valid``: per angle, for estimates with status VALID: count, sum of (err / sigma)^2, count within 2 sigma.
    """
    if not records:
        return {}
    masks = _phase_masks(records[0], first_scan)
    err = {a: np.array([r["err"][a] for r in records], dtype=np.float64) for a in PHASE_ANGLES}
    sig = {a: np.array([r["sigma"][a] for r in records], dtype=np.float64) for a in PHASE_ANGLES}
    load = np.array([r["load_factor_true"] for r in records], dtype=np.float64)
    nees = np.array([r["nees"] for r in records], dtype=np.float64)
    valid = np.array([[s == "VALID" for s in r["status"]] for r in records])
    lo9, hi9 = chi2.ppf(0.025, NEES_DOF), chi2.ppf(0.975, NEES_DOF)
    out: dict[str, dict[str, Any]] = {}
    for name, m in masks.items():
        if not m.any():
            continue
        cols = np.flatnonzero(m)
        entry: dict[str, Any] = {"n": int(len(records) * cols.size), "sq": {}, "count": {}, "valid": {}}
        for a in PHASE_ANGLES:
            e = err[a][:, cols]
            ok = np.isfinite(e)
            if a in ROLL_ANGLES:
                ok &= load[:, cols] >= MIN_LOAD_ROLL
            entry["sq"][a] = float(np.sum(np.where(ok, e * e, 0.0)))
            entry["count"][a] = int(ok.sum())
            s = sig[a][:, cols]
            v = ok & valid[:, cols] & np.isfinite(s) & (s > 0.0)
            z = np.where(v, e / np.where(v, s, 1.0), 0.0)
            entry["valid"][a] = {
                "n": int(v.sum()),
                "z2": float(np.sum(z * z)),
                "in2": int(np.sum(v & (np.abs(z) <= 2.0))),
            }
        nc = nees[:, cols]
        okn = np.isfinite(nc)
        per_scan_n = okn.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            anees = np.where(per_scan_n > 0, np.where(okn, nc, 0.0).sum(axis=0) / np.maximum(per_scan_n, 1), np.nan)
        entry["anees"] = [(float(a_), int(n_)) for a_, n_ in zip(anees, per_scan_n, strict=True) if n_ > 0]
        entry["nees_sum"] = float(np.sum(np.where(okn, nc, 0.0)))
        entry["nees_n"] = int(okn.sum())
        entry["nees_in"] = int(np.sum(okn & (nc >= lo9) & (nc <= hi9)))
        out[name] = entry
    return out


def phase_table(samples: Sequence[Mapping[str, Mapping[str, Any]]]) -> dict[str, dict[str, Any]]:
    """Pool :func:`phase_samples` of several targets: per phase the RMS error of each angle (deg), the defined
    fraction of the heading, the NEES (mean ANEES over the phase's scans; fraction of scans whose ANEES lies in
    its 95 % band [chi2(9N, 0.025) / N, chi2(9N, 0.975) / N] for N runs; mean per-sample NEES and the fraction
    of samples inside the chi2(9) 95 % interval) and the VALID consistency (per angle: the share of estimates
    VALID, the mean (err / sigma)^2 over them -- 1 if the sigmas are right -- and the fraction within 2 sigma,
    0.954 if Gaussian and right)."""
    out: dict[str, dict[str, Any]] = {}
    for name in PHASES:
        parts = [s[name] for s in samples if name in s]
        if not parts:
            continue
        n = sum(p["n"] for p in parts)
        row: dict[str, Any] = {"samples": n, "rms_deg": {}, "defined": {}, "valid": {}}
        for a in PHASE_ANGLES:
            cnt = sum(p["count"][a] for p in parts)
            row["rms_deg"][a] = math.sqrt(sum(p["sq"][a] for p in parts) / cnt) if cnt else None
            row["defined"][a] = cnt / n if n else None
            vn = sum(p["valid"][a]["n"] for p in parts)
            row["valid"][a] = {
                "share": vn / n if n else None,
                "mean_z2": sum(p["valid"][a]["z2"] for p in parts) / vn if vn else None,
                "within_2sigma": sum(p["valid"][a]["in2"] for p in parts) / vn if vn else None,
            }
        anees = [(a, k) for p in parts for a, k in p["anees"]]
        inside = [chi2.ppf(0.025, NEES_DOF * k) / k <= a <= chi2.ppf(0.975, NEES_DOF * k) / k for a, k in anees]
        nn = sum(p["nees_n"] for p in parts)
        runs = [k for _, k in anees]
        row["nees"] = {
            "anees_mean": float(np.mean([a for a, _ in anees])) if anees else None,
            "anees_in_band": float(np.mean(inside)) if inside else None,
            "runs_per_scan": [min(runs), max(runs)] if runs else None,
            "band_at_min_runs": (
                [chi2.ppf(0.025, NEES_DOF * min(runs)) / min(runs), chi2.ppf(0.975, NEES_DOF * min(runs)) / min(runs)]
                if runs
                else None
            ),
            "sample_mean": sum(p["nees_sum"] for p in parts) / nn if nn else None,
            "sample_in_95": sum(p["nees_in"] for p in parts) / nn if nn else None,
        }
        out[name] = row
    return out
