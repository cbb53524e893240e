"""What every estimator's section shares: errors against truth, NEES, and the standard figures.

Figures are matplotlib (Agg backend, no display) rendered to PNG and embedded in the HTML as base64, so the
report is one self-contained file. Long series are decimated to at most :data:`MAX_POINTS` points per line
(an even stride that keeps the last sample) and plan views draw at most :data:`MAX_ELLIPSES` covariance
ellipses, so a one-hour recording plots as fast as a one-minute one.

NEES (normalised estimation error squared) of an estimate with error e and covariance P is eᵀP⁻¹e; for a
consistent filter it follows χ² with as many degrees of freedom as e has components. The NEES figure shows
each sample with the two-sided 95 % χ² interval of one sample, and the headline gives the share of samples
inside it (≈ 95 % for a consistent filter; well below: over-confident; far above: pessimistic, often with
many samples under the lower bound).
"""

from __future__ import annotations

import base64
import io
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure as MplFigure
from matplotlib.patches import Ellipse
from matplotlib.ticker import LogFormatter, NullFormatter
from scipy.stats import chi2

from shared.foxglove.frames import F64, Estimate

from ..data import RunData, TruthSeries

MAX_POINTS = 2000
MAX_ELLIPSES = 40
#: platforms (rows) of an error-against-time figure, at most
MAX_ERROR_PANELS = 6
#: probability of the NEES band drawn and scored
NEES_BAND_P = 0.95
#: every figure is this wide (inches) and drawn at this resolution: 1560 px, shown at the page's width (about
#: 1200 px), so it stays sharp when the browser zooms, and a click shows it at full size
FIG_WIDTH_IN = 12.0
DPI = 130
#: colours of the embedded PNGs (:func:`png_bytes`)
PALETTE_COLOURS = 128

plt.rcParams.update(
    {
        "font.size": 10.5,
        "axes.titlesize": 11.5,
        "axes.labelsize": 10.5,
        "axes.grid": True,
        "grid.alpha": 0.3,
        "legend.fontsize": 9.5,
        "figure.autolayout": False,
    }
)


@dataclass
class Figure:
    """One embedded figure: title, caption and the PNG as base64."""

    title: str
    png_b64: str
    caption: str = ""


@dataclass
class Section:
    """One estimator (instance or group) of the report."""

    kind: str
    instance: str
    title: str
    #: headline metric name -> value (JSON-able); shown in the summary table and saved in metrics.json
    headline: dict[str, Any] = field(default_factory=dict)
    figures: list[Figure] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    #: tables: (caption, header, rows)
    tables: list[tuple[str, list[str], list[list[Any]]]] = field(default_factory=list)


def new_figure(rows: int = 1, cols: int = 1, height: float = 3.0, width: float = FIG_WIDTH_IN) -> tuple[MplFigure, Any]:
    """A figure of ``rows`` x ``cols`` axes; ``height`` per row in inches of a 9-inch-wide figure (scaled with the
    width, so the story figures keep their proportions)."""
    fig, axes = plt.subplots(rows, cols, figsize=(width, height * rows * width / 9.0), squeeze=False)
    return fig, axes


def apply_margins(fig: MplFigure, left_in: float = 1.0, bottom_in: float = 0.65, hspace_in: float = 0.8) -> None:
    """Fixed margins in inches: ``left_in`` for the y labels, ``bottom_in`` for the x label (and a legend below),
    ``hspace_in`` between rows for their titles and x labels."""
    w, h = fig.get_size_inches()
    specs = [spec for ax in fig.axes if (spec := ax.get_subplotspec()) is not None]
    rows = max((spec.get_gridspec().nrows for spec in specs), default=1)
    top, bottom = 1.0 - 0.45 / h, bottom_in / h
    row_h = (top - bottom) * h / rows
    fig.subplots_adjust(
        left=left_in / w,
        right=1.0 - 0.25 / w,
        top=top,
        bottom=bottom,
        hspace=hspace_in / max(row_h - hspace_in, 0.5),
        wspace=0.28,
    )


def render(
    fig: MplFigure,
    title: str,
    caption: str = "",
    left_in: float = 1.0,
    bottom_in: float = 0.65,
    hspace_in: float = 0.8,
) -> Figure:
    """The figure as an embedded PNG (the figure is closed), with :func:`apply_margins` rather than
    ``tight_layout``, which costs a full extra draw."""
    apply_margins(fig, left_in, bottom_in, hspace_in)
    return Figure(title, base64.b64encode(png_bytes(fig)).decode("ascii"), caption)


def png_bytes(fig: MplFigure) -> bytes:
    """The figure drawn at :data:`DPI` as a PNG of at most :data:`PALETTE_COLOURS` colours (the figure is closed).

    Line plots use few colours; a palette PNG (Pillow's fast octree quantiser, no dithering) is a third of the
    size of matplotlib's true-colour PNG, with no visible difference, so the page stays small at this resolution.
    """
    from PIL import Image

    fig.set_dpi(DPI)
    canvas = fig.canvas
    canvas.draw()
    width, height = canvas.get_width_height(physical=True)
    rgba = Image.frombuffer("RGBA", (width, height), canvas.buffer_rgba(), "raw", "RGBA", 0, 1)  # type: ignore[attr-defined]
    plt.close(fig)
    pal = rgba.convert("RGB").quantize(PALETTE_COLOURS, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE)
    buf = io.BytesIO()
    pal.save(buf, format="PNG", compress_level=6)
    return buf.getvalue()


def decimate(n: int, max_points: int = MAX_POINTS) -> np.ndarray:
    """Indices of at most ``max_points`` of ``n`` samples: an even stride, the last sample kept."""
    if n <= max_points:
        return np.arange(n)
    idx = np.unique(np.linspace(0, n - 1, max_points).round().astype(np.int64))
    return idx


def nees_band(dof: int, p: float = NEES_BAND_P) -> tuple[float, float]:
    """Two-sided ``p`` interval of one χ²(dof) sample."""
    a = (1.0 - p) / 2.0
    return float(chi2.ppf(a, dof)), float(chi2.ppf(1.0 - a, dof))


def nees(err: F64, cov: F64) -> F64:
    """eᵀP⁻¹e per row: ``err`` (n, d), ``cov`` (n, d, d); NaN where P is singular or e is NaN."""
    n = err.shape[0]
    out = np.full(n, np.nan)
    ok = np.all(np.isfinite(err), axis=1) & np.all(np.isfinite(cov.reshape(n, -1)), axis=1)
    if not ok.any():
        return out
    e, c = err[ok], cov[ok]
    try:
        out[ok] = np.einsum("ni,ni->n", e, np.linalg.solve(c, e[..., None])[..., 0])
    except np.linalg.LinAlgError:  # some P singular: one by one
        idx = np.flatnonzero(ok)
        for k, i in enumerate(idx):
            try:
                out[i] = float(e[k] @ np.linalg.solve(c[k], e[k]))
            except np.linalg.LinAlgError:
                continue
    return out


def in_band_fraction(values: F64, dof: int) -> float | None:
    v = values[np.isfinite(values)]
    if v.size == 0:
        return None
    lo, hi = nees_band(dof)
    return float(np.mean((v >= lo) & (v <= hi)))


def rms(values: Iterable[float]) -> float | None:
    v = np.asarray(list(values), dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v * v))) if v.size else None


def r(value: float | None, digits: int = 3) -> float | None:
    """A number for the headline: rounded to ``digits`` significant digits (None stays None)."""
    if value is None or not math.isfinite(value):
        return None
    if value == 0:
        return 0.0
    return float(f"{value:.{digits}g}")


@dataclass
class ErrorSeries:
    """Estimates of one platform against its truth: stamps (s), ENU errors (n, 3), covariances (n, 3, 3)."""

    name: str
    t_s: F64
    est: F64
    truth: F64
    cov: F64 | None
    horizontal_only: bool

    @property
    def err(self) -> F64:
        return np.asarray(self.est - self.truth, dtype=np.float64)

    @property
    def dims(self) -> int:
        return 2 if self.horizontal_only else 3

    def nees(self) -> F64:
        if self.cov is None:
            return np.full(self.t_s.size, np.nan)
        d = self.dims
        return nees(self.err[:, :d], self.cov[:, :d, :d])

    def horizontal_error(self) -> F64:
        e = self.err
        return np.asarray(np.hypot(e[:, 0], e[:, 1]), dtype=np.float64)


def error_series(
    name: str, estimates: Sequence[Estimate], truth: TruthSeries | None, horizontal_only: bool | None = None
) -> ErrorSeries | None:
    """The estimates (one platform, stamp order) against the truth interpolated at their stamps; NEES in 2-D
    (horizontal) when ``horizontal_only`` (default: if any estimate says so), else 3-D."""
    if not estimates or truth is None:
        return None
    t = np.array([e.stamp_ns for e in estimates], dtype=np.float64) / 1e9
    est = np.array([e.position for e in estimates], dtype=np.float64).reshape(-1, 3)
    covs = None
    if all(e.cov is not None for e in estimates):
        covs = np.array([e.cov for e in estimates], dtype=np.float64).reshape(-1, 3, 3)
    tr = truth.at(t)
    ok = np.all(np.isfinite(tr), axis=1)
    if not ok.any():
        return None
    return ErrorSeries(
        name,
        t[ok],
        est[ok],
        tr[ok],
        None if covs is None else covs[ok],
        horizontal_only=any(e.horizontal_only for e in estimates) if horizontal_only is None else horizontal_only,
    )


# ----- figures ------------------------------------------------------------------------------------------------


def cov_ellipse(center: Sequence[float], cov2: F64, nsig: float = 3.0, **kw: Any) -> Ellipse:
    vals, vecs = np.linalg.eigh(np.asarray(cov2, dtype=np.float64))
    vals = np.clip(vals, 0.0, None)
    angle = math.degrees(math.atan2(vecs[1, 1], vecs[0, 1]))
    return Ellipse(
        (float(center[0]), float(center[1])),
        2 * nsig * math.sqrt(vals[1]),
        2 * nsig * math.sqrt(vals[0]),
        angle=angle,
        fill=False,
        **kw,
    )


def robust_limit(values: Iterable[F64], sigmas: Iterable[F64]) -> float | None:
    """A symmetric y limit that shows the errors and the usual ±3σ band: 1.25 × the larger of the 99th
    percentile of |error| and the median 3σ — so one early transient (a km-wide σ at initiation) does not flatten
    the rest. None when there is nothing finite."""
    errs = np.concatenate([np.abs(np.asarray(v, dtype=np.float64)).ravel() for v in values] or [np.zeros(0)])
    sig = np.concatenate([np.asarray(v, dtype=np.float64).ravel() for v in sigmas] or [np.zeros(0)])
    errs, sig = errs[np.isfinite(errs)], sig[np.isfinite(sig)]
    if errs.size == 0:
        return None
    lim = max(float(np.percentile(errs, 99)), 3.0 * float(np.median(sig)) if sig.size else 0.0)
    return 1.25 * lim if lim > 0 else None


def error_plot(ax: Axes, t: F64, err: F64, sigma: F64 | None, color: str, unit: str = "m") -> bool:
    """An error component against time with its ±3σ envelope; True if the axis clips some of it."""
    idx = decimate(t.size)
    ax.plot(t[idx], err[idx], lw=1.0, color=color, label="estimate − truth")
    if sigma is not None:
        s = 3.0 * sigma[idx]
        ax.fill_between(t[idx], -s, s, color=color, alpha=0.18, lw=0, label="±3σ of the filter")
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_xlabel("t, s")
    lim = robust_limit([err], [] if sigma is None else [sigma])
    if lim is None:
        return False
    ax.set_ylim(-lim, lim)
    worst = max(float(np.nanmax(np.abs(err))) if np.isfinite(err).any() else 0.0, 0.0)
    if sigma is not None and np.isfinite(sigma).any():
        worst = max(worst, 3.0 * float(np.nanmax(sigma)))
    return worst > lim


def error_figure(series: list[ErrorSeries], axes_names: tuple[str, str], what: str = "") -> tuple[Figure, bool]:
    """One row per platform (at most :data:`MAX_ERROR_PANELS`), one column per horizontal axis, each with its
    own ±3σ band: bands of several platforms never overlap. (figure, whether platforms were left out)"""
    shown = series[:MAX_ERROR_PANELS]
    fig, axs = new_figure(rows=len(shown), cols=2, height=2.0)
    palette = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    clipped = False
    for r, s in enumerate(shown):
        for c, name in enumerate(axes_names):
            ax = axs[r][c]
            sig = None if s.cov is None else np.sqrt(np.clip(s.cov[:, c, c], 0.0, None))
            clipped |= error_plot(ax, s.t_s, s.err[:, c], sig, palette[r % len(palette)])
            ax.set_title(f"{s.name}: {name} error")
            ax.set_ylabel(f"{name.split(' ')[0]} error, m")
    caption = "line: estimate − truth per axis and platform; shaded: ±3σ of the filter's covariance"
    if clipped:
        caption += "; y axes clipped at 1.25 × the larger of the 99th percentile of |error| and the median 3σ"
    return render(fig, f"Error against time{what}", caption, hspace_in=0.9), len(series) > len(shown)


def nees_plot(ax: Axes, series: dict[str, tuple[F64, F64]], dof: int) -> None:
    """NEES samples per series against the two-sided 95 % χ²(dof) interval of one sample; the legend gives each
    series' share inside it."""
    lo, hi = nees_band(dof)
    for name, (t, v) in series.items():
        idx = decimate(t.size)
        share = in_band_fraction(v, dof)
        label = name if share is None else f"{name} ({share:.0%} inside)"
        ax.plot(t[idx], v[idx], ".", ms=4, label=label)
    ax.axhspan(lo, hi, color="g", alpha=0.12, label=f"95 % interval of χ²({dof}): [{lo:.2g}, {hi:.2g}]")
    ax.axhline(dof, color="g", lw=0.8)
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(LogFormatter(labelOnlyBase=True))  # plain text, no mathtext: faster
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("t, s")
    ax.set_ylabel("NEES (dimensionless)")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.24), ncol=min(4, len(series) + 1), frameon=False)


def standard_figures(
    series: list[ErrorSeries],
    *,
    plan_truths: dict[str, F64],
    plan_estimates: dict[str, tuple[F64, F64 | None]],
    points: dict[str, F64] | None = None,
    axes_names: tuple[str, str] = ("east", "north"),
    what: str = "",
    plan_focus: dict[str, F64] | None = None,
) -> tuple[list[Figure], dict[str, Any]]:
    """Plan views (the scene and each track zoomed — to ``plan_focus`` of a track if given), horizontal error
    components with ±3σ per platform, NEES with its χ² band; plus their headline numbers."""
    from .plan import plan_figure

    figs: list[Figure] = [plan_figure(plan_truths, plan_estimates, points, title=f"Plan view{what}", focus=plan_focus)]
    head: dict[str, Any] = {}
    usable = [s for s in series if s.t_s.size]
    if not usable:
        return figs, head
    figs.append(error_figure(usable, axes_names, what)[0])
    with_cov = [s for s in usable if s.cov is not None]
    if with_cov:
        dof = with_cov[0].dims
        mfig, ax = new_figure(height=3.2)
        nees_series = {s.name: (s.t_s, s.nees()) for s in with_cov if s.dims == dof}
        nees_plot(ax[0][0], nees_series, dof)
        ax[0][0].set_title(f"NEES of the {dof}-D position per estimate (log scale)")
        caption = "eᵀP⁻¹e per estimate; band: the two-sided 95 % interval of one χ² sample"
        legend_in = 0.35 * math.ceil((len(nees_series) + 1) / 4)
        figs.append(render(mfig, f"NEES{what}", caption, bottom_in=0.95 + legend_in))
        all_nees = np.concatenate([s.nees() for s in with_cov if s.dims == dof])
        head["nees_dof"] = dof
        head["nees_mean"] = r(float(np.nanmean(all_nees))) if np.isfinite(all_nees).any() else None
        head["nees_in_95_band"] = r(in_band_fraction(all_nees, dof))
    herr = np.concatenate([s.horizontal_error() for s in usable])
    head["horizontal_error_rms_m"] = r(rms(herr))
    head["horizontal_error_max_m"] = r(float(np.max(herr))) if herr.size else None
    return figs, head


__all__ = [
    "DPI",
    "FIG_WIDTH_IN",
    "MAX_ELLIPSES",
    "MAX_ERROR_PANELS",
    "MAX_POINTS",
    "ErrorSeries",
    "Figure",
    "RunData",
    "Section",
    "apply_margins",
    "cov_ellipse",
    "decimate",
    "error_figure",
    "error_plot",
    "error_series",
    "in_band_fraction",
    "nees",
    "nees_band",
    "nees_plot",
    "new_figure",
    "r",
    "render",
    "rms",
    "robust_limit",
    "standard_figures",
]
