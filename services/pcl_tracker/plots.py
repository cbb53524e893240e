"""Validation and normalisation of the plots of one scan (digest 003 §5.2, §5.6).

Each plot becomes z_b = [r_b m, alpha rad (wrapped to (-pi, pi]), eps rad, v_b m/s] with its sigmas in the
same units. Refused plots are counted by reason; kept-but-unusual plots are counted by flag.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

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


def _finite(v: float | None) -> bool:
    return v is not None and isinstance(v, int | float) and math.isfinite(v)


def normalise_plots(
    plots: Sequence[BistaticPlot], cfg: PclTrackerConfig, L_m: float, wavelength_m: float | None
) -> NormalisedPlots:
    """Apply the §5.6 bad-input rules to every plot of a scan."""
    geo, lim, md = cfg.geometry, cfg.limits, cfg.measurement_defaults
    defaults = cfg.default_sigmas()
    rejected: Counter[str] = Counter()
    flagged: Counter[str] = Counter()
    rows: list[tuple[str, list[float], list[float], float, bool]] = []
    seen: set[str] = set()
    el_min, el_max = math.radians(lim.el_min_deg), math.radians(lim.el_max_deg)
    for p in plots:
        if p.plot_id in seen:
            rejected["duplicate_plot_id"] += 1
            continue
        seen.add(p.plot_id)
        # ---- range form -> r_b
        forms = [p.bistatic_range_m, p.range_sum_m, p.delay_s]
        vforms = [p.bistatic_velocity_mps, p.doppler_hz]
        if sum(f is not None for f in forms) != 1 or sum(f is not None for f in vforms) != 1:
            rejected["missing_quantity"] += 1
            continue
        if not all(_finite(v) for v in (*[f for f in forms if f is not None], *[f for f in vforms if f is not None])):
            rejected["nan"] += 1
            continue
        if not (_finite(p.azimuth_deg) and _finite(p.elevation_deg)):
            rejected["nan"] += 1
            continue
        if p.bistatic_range_m is not None:
            r_b = float(p.bistatic_range_m)
        elif p.range_sum_m is not None:
            r_b = float(p.range_sum_m) - L_m
        else:
            r_b = geo.c_mps * float(p.delay_s)  # type: ignore[arg-type]
        if p.bistatic_velocity_mps is not None:
            v_b = float(p.bistatic_velocity_mps)
        else:
            if wavelength_m is None:
                rejected["no_wavelength"] += 1
                continue
            v_b = geo.doppler_sign * wavelength_m * float(p.doppler_hz)  # type: ignore[arg-type]
        # ---- sigmas: absent, non-finite, <= 0 or absurd -> default (flag)
        given = [p.sigma_rb_m, p.sigma_az_deg, p.sigma_el_deg, p.sigma_vb_mps]
        scale = [1.0, math.pi / 180.0, math.pi / 180.0, 1.0]
        default_native = [md.sigma_rb_m, md.sigma_az_deg, md.sigma_el_deg, md.sigma_vb_mps]
        sig: list[float] = []
        defaulted = False
        for g, s, dflt_native, dflt in zip(given, scale, default_native, defaults, strict=True):
            if g is None:
                sig.append(dflt)
                continue
            if not _finite(g) or g <= 0.0 or g > md.absurd_factor * dflt_native:
                defaulted = True
                sig.append(dflt)
            else:
                sig.append(float(g) * s)
        if defaulted:
            flagged["sigma_defaulted"] += 1
        # ---- impossible geometry and limits
        if r_b < 0.0:
            if r_b >= -lim.near_baseline_sigmas * sig[0]:
                r_b = 0.0
                flagged["near_baseline"] += 1
            else:
                rejected["rb_below_baseline"] += 1
                continue
        el = math.radians(float(p.elevation_deg))
        if r_b > lim.rb_max_m or abs(v_b) > lim.vb_max_abs_mps or not (el_min <= el <= el_max):
            rejected["out_of_range"] += 1
            continue
        az = math.pi - math.fmod(math.pi - math.radians(float(p.azimuth_deg)), 2.0 * math.pi)
        if az <= -math.pi:
            az += 2.0 * math.pi
        elif az > math.pi:
            az -= 2.0 * math.pi
        low = r_b < lim.rb_min_convertible_m
        if low:
            flagged["low_rb"] += 1
        snr = float(p.snr_db) if p.snr_db is not None and _finite(p.snr_db) else math.nan
        rows.append((p.plot_id, [r_b, az, el, v_b], sig, snr, low))
    rows.sort(key=lambda r: r[0])
    n = len(rows)
    return NormalisedPlots(
        ids=[r[0] for r in rows],
        z=np.array([r[1] for r in rows], dtype=np.float64).reshape(n, 4),
        sig=np.array([r[2] for r in rows], dtype=np.float64).reshape(n, 4),
        snr_db=np.array([r[3] for r in rows], dtype=np.float64).reshape(n),
        low_rb=np.array([r[4] for r in rows], dtype=bool).reshape(n),
        rejected=rejected,
        flagged=flagged,
    )
