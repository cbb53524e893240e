"""Validation and normalisation of the plots of one scan (digest 003 §5.2, §5.6).

Each plot becomes z_b = [r_b m, alpha rad (wrapped to (-pi, pi]), eps rad, v_b m/s] with its sigmas in the
same units. Refused plots are counted by reason; kept-but-unusual plots are counted by flag.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from operator import attrgetter
from typing import Any

import numpy as np
from pydantic import ValidationError

from schemas.radar import BistaticPlot

from .config import PclTrackerConfig
from .geometry import BoolArray, FloatArray


@dataclass
class NormalisedPlots:
    """The usable plots of a scan, sorted by plot_id (the association tie-break order)."""

    ids: list[str]
    z: FloatArray  # (P, 4) [r_b m, alpha rad, eps rad, v_b m/s]
    sig: FloatArray  # (P, 4) same units
    snr_db: FloatArray  # (P,) NaN when absent
    low_rb: BoolArray  # (P,) r_b < rb_min_convertible_m: may be assigned, never converted
    rejected: Counter[str] = field(default_factory=Counter)
    flagged: Counter[str] = field(default_factory=Counter)

    def __len__(self) -> int:
        return len(self.ids)


_FIELDS = (
    "azimuth_deg",
    "elevation_deg",
    "bistatic_range_m",
    "range_sum_m",
    "delay_s",
    "bistatic_velocity_mps",
    "doppler_hz",
    "sigma_rb_m",
    "sigma_az_deg",
    "sigma_el_deg",
    "sigma_vb_mps",
    "snr_db",
)
_AZ, _EL, _RB, _RSUM, _DELAY, _VB, _FD, _SIG0, _SNR = 0, 1, 2, 3, 4, 5, 6, 7, 11
_get_fields = attrgetter(*_FIELDS)
_TWO_PI = 2.0 * math.pi
_DEG2RAD = math.pi / 180.0


def _as_float(v: object) -> float:
    """A plot value as a float; NaN for anything that is not a real number (only unvalidated input)."""
    if isinstance(v, int | float):
        return float(v)
    return math.nan


def _table(plots: Sequence[BistaticPlot]) -> tuple[FloatArray, BoolArray]:
    """The numeric fields of every plot (n, 12) with NaN for absent values, and which were present."""
    n = len(plots)
    raw = np.empty((n, len(_FIELDS)), dtype=object)
    if n:
        raw[:] = [_get_fields(p) for p in plots]
    present = np.not_equal(raw, None)  # type: ignore[call-overload]
    filled = np.where(present, raw, np.nan)
    try:
        vals = filled.astype(np.float64)
    except (TypeError, ValueError):
        vals = np.vectorize(_as_float, otypes=[np.float64])(filled).reshape(n, len(_FIELDS))
    return vals, np.asarray(present, dtype=bool)


def normalise_plots(
    plots: Sequence[BistaticPlot], cfg: PclTrackerConfig, L_m: float, wavelength_m: float | None
) -> NormalisedPlots:
    """Apply the §5.6 bad-input rules to every plot of a scan (vectorised over the plots).

    Order of the checks, as each plot meets them: a repeated plot_id (``duplicate_plot_id``), not exactly
    one range and one velocity form (``missing_quantity``), a non-finite value (``nan``), Doppler without
    a wavelength (``no_wavelength``); sigmas absent → default, non-finite/≤ 0/absurd → default and
    ``sigma_defaulted``; r_b < 0 → clamped to 0 (``near_baseline``) within ``near_baseline_sigmas`` σ, else
    ``rb_below_baseline``; limits → ``out_of_range``; r_b below ``rb_min_convertible_m`` → ``low_rb``.
    """
    geo, lim, md = cfg.geometry, cfg.limits, cfg.measurement_defaults
    defaults = np.array(cfg.default_sigmas())
    default_native = np.array([md.sigma_rb_m, md.sigma_az_deg, md.sigma_el_deg, md.sigma_vb_mps])
    scale = np.array([1.0, _DEG2RAD, _DEG2RAD, 1.0])
    rejected: Counter[str] = Counter()
    flagged: Counter[str] = Counter()
    n = len(plots)
    ids = [p.plot_id for p in plots]
    V, present = _table(plots)

    def reject(mask: BoolArray, reason: str) -> None:
        k = int(mask.sum())
        if k:
            rejected[reason] += k

    seen: set[str] = set()
    alive = np.ones(n, dtype=bool)
    for i, pid in enumerate(ids):
        if pid in seen:
            alive[i] = False
        seen.add(pid)
    reject(~alive, "duplicate_plot_id")
    forms_ok = (present[:, _RB : _DELAY + 1].sum(axis=1) == 1) & (present[:, _VB : _FD + 1].sum(axis=1) == 1)
    reject(alive & ~forms_ok, "missing_quantity")
    alive &= forms_ok
    rng_val = np.where(present[:, _RB], V[:, _RB], np.where(present[:, _RSUM], V[:, _RSUM], V[:, _DELAY]))
    vel_val = np.where(present[:, _VB], V[:, _VB], V[:, _FD])
    finite = np.isfinite(rng_val) & np.isfinite(vel_val) & np.isfinite(V[:, _AZ]) & np.isfinite(V[:, _EL])
    reject(alive & ~finite, "nan")
    alive &= finite
    with np.errstate(invalid="ignore"):
        r_b = np.where(
            present[:, _RB], V[:, _RB], np.where(present[:, _RSUM], V[:, _RSUM] - L_m, geo.c_mps * V[:, _DELAY])
        )
        if wavelength_m is None:
            no_wl = alive & ~present[:, _VB]
            reject(no_wl, "no_wavelength")
            alive &= ~no_wl
            v_b = V[:, _VB].copy()
        else:
            v_b = np.where(present[:, _VB], V[:, _VB], (geo.doppler_sign * wavelength_m) * V[:, _FD])
        # sigmas: absent -> default; non-finite, <= 0 or absurd -> default and flagged
        g = V[:, _SIG0 : _SIG0 + 4]
        given = present[:, _SIG0 : _SIG0 + 4]
        bad = given & ~(np.isfinite(g) & (g > 0.0) & (g <= md.absurd_factor * default_native))
        use_default = ~given | bad
        sig = np.where(use_default, defaults, g * scale)
        k = int((alive & bad.any(axis=1)).sum())
        if k:
            flagged["sigma_defaulted"] += k
        # impossible geometry and limits
        neg = alive & (r_b < 0.0)
        near = neg & (r_b >= -lim.near_baseline_sigmas * sig[:, 0])
        if near.any():
            flagged["near_baseline"] += int(near.sum())
            r_b = np.where(near, 0.0, r_b)
        reject(neg & ~near, "rb_below_baseline")
        alive &= ~(neg & ~near)
        el = V[:, _EL] * _DEG2RAD
        out = (r_b > lim.rb_max_m) | (np.abs(v_b) > lim.vb_max_abs_mps)
        out |= ~((math.radians(lim.el_min_deg) <= el) & (el <= math.radians(lim.el_max_deg)))
        reject(alive & out, "out_of_range")
        alive &= ~out
        az = math.pi - np.fmod(math.pi - V[:, _AZ] * _DEG2RAD, _TWO_PI)
        az = np.where(az <= -math.pi, az + _TWO_PI, np.where(az > math.pi, az - _TWO_PI, az))
        low = alive & (r_b < lim.rb_min_convertible_m)
        if low.any():
            flagged["low_rb"] += int(low.sum())
    keep = np.flatnonzero(alive)
    keep = keep[sorted(range(keep.size), key=lambda k: ids[keep[k]])]
    snr = V[keep, _SNR]
    return NormalisedPlots(
        ids=[ids[i] for i in keep],
        z=np.stack([r_b[keep], az[keep], el[keep], v_b[keep]], axis=-1).reshape(keep.size, 4),
        sig=sig[keep].reshape(keep.size, 4),
        snr_db=np.where(np.isfinite(snr), snr, np.nan),
        low_rb=low[keep],
        rejected=rejected,
        flagged=flagged,
    )


# ----- plots that fail the wire schema (the service's decoding, §5.6) ---------------------------------------


def _plot_reason(exc: ValidationError) -> str:
    """The reason a plot failed validation: ``nan``, ``out_of_range``, ``missing_quantity``, ``invalid_plot``."""
    kinds = {str(e.get("type", "")) for e in exc.errors(include_url=False)}
    if "finite_number" in kinds:
        return "nan"
    if kinds & {"greater_than_equal", "less_than_equal", "greater_than", "less_than"}:
        return "out_of_range"
    if "value_error" in kinds:
        return "missing_quantity"
    return "invalid_plot"


_SIGMAS = ("sigma_rb_m", "sigma_az_deg", "sigma_el_deg", "sigma_vb_mps")


def _sanitised(plot: Any) -> dict[str, Any] | None:
    """A plot whose non-finite *sigmas* are passed on as invalid (-1) and non-finite SNR as absent, or None.

    Digest §5.6: a NaN, non-positive or absurd sigma is replaced by the configured default and flagged
    ``sigma_defaulted`` (the core does that for -1); it does not make the plot unusable. The wire format
    refuses NaN, so this is the one place that turns it into a value the core treats as invalid.
    """
    if not isinstance(plot, dict):
        return None
    bad = [k for k in _SIGMAS if isinstance(plot.get(k), float) and not math.isfinite(plot[k])]
    snr = plot.get("snr_db")
    bad_snr = isinstance(snr, float) and not math.isfinite(snr)
    if not bad and not bad_snr:
        return None
    fixed = dict(plot)
    for k in bad:
        fixed[k] = -1.0
    if bad_snr:
        fixed["snr_db"] = None
    return fixed


def salvage_plots(plots: list[Any]) -> tuple[list[Any], Counter[str]]:
    """The plots of an undecodable scan that pass the schema (NaN sigmas / SNR repaired by :func:`_sanitised`),
    and the others counted by reason (``nan``, ``out_of_range``, ``missing_quantity``, ``invalid_plot``)."""
    good: list[Any] = []
    dropped: Counter[str] = Counter()
    for p in plots:
        try:
            BistaticPlot.model_validate(p, strict=True)
            good.append(p)
            continue
        except ValidationError as pexc:
            err = pexc
        fixed = _sanitised(p)
        if fixed is not None:
            try:
                BistaticPlot.model_validate(fixed, strict=True)
                good.append(fixed)
                continue
            except ValidationError as pexc:
                err = pexc
        dropped[_plot_reason(err)] += 1
    return good, dropped
