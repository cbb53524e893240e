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
#: probability of the NEES band drawn and scored
NEES_BAND_P = 0.95
DPI = 80

plt.rcParams.update(
    {
        "font.size": 8,
        "axes.titlesize": 9,
        "axes.grid": True,
        "grid.alpha": 0.3,
        "legend.fontsize": 7,
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


def new_figure(rows: int = 1, cols: int = 1, height: float = 3.0, width: float = 9.0) -> tuple[MplFigure, Any]:
    fig, axes = plt.subplots(rows, cols, figsize=(width, height * rows), squeeze=False)
    return fig, axes


def render(fig: MplFigure, title: str, caption: str = "", left_in: float = 0.75) -> Figure:
    """The figure as an embedded PNG (the figure is closed). Fixed margins (``left_in`` inches for the y labels)
    rather than ``tight_layout``, which costs a full extra draw."""
    w, h = fig.get_size_inches()
    fig.subplots_adjust(
        left=left_in / w, right=1.0 - 0.2 / w, top=1.0 - 0.35 / h, bottom=0.5 / h, hspace=0.75, wspace=0.25
    )
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    plt.close(fig)
    return Figure(title, base64.b64encode(buf.getvalue()).decode("ascii"), caption)


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


def plan_view(
    ax: Axes,
    truths: dict[str, F64],
    estimates: dict[str, tuple[F64, F64 | None]],
    *,
    points: dict[str, F64] | None = None,
    title: str = "plan view (east, north)",
    equal: bool = True,
) -> None:
    """Truth tracks (lines), estimates (dots) with every k-th 3σ ellipse, optional fixed points (markers)."""
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (name, xy) in enumerate(truths.items()):
        idx = decimate(len(xy))
        ax.plot(xy[idx, 0], xy[idx, 1], "-", color=colors[i % len(colors)], lw=1.2, label=f"{name} truth")
    for i, (name, (xy, covs)) in enumerate(estimates.items()):
        if len(xy) == 0:
            continue
        c = colors[(i + len(truths)) % len(colors)] if name not in truths else colors[list(truths).index(name)]
        idx = decimate(len(xy))
        ax.plot(xy[idx, 0], xy[idx, 1], ".", ms=2.5, color=c, alpha=0.8, label=f"{name} estimate")
        if covs is not None and len(covs):
            step = max(1, len(xy) // max(1, MAX_ELLIPSES // max(1, len(estimates))))
            for k in range(0, len(xy), step):
                ax.add_patch(cov_ellipse(xy[k], covs[k][:2, :2], color=c, lw=0.6, alpha=0.6))
    for name, xy in (points or {}).items():
        ax.plot(xy[:, 0], xy[:, 1], "k^", ms=6)
        ax.annotate(name, (float(xy[0, 0]), float(xy[0, 1])), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xlabel("east, m")
    ax.set_ylabel("north, m")
    ax.set_title(title + " — ellipses: 3σ")
    if equal:
        ax.set_aspect("equal", adjustable="datalim")
    if truths or estimates:
        ax.legend(loc="best", ncol=2)


def error_plot(ax: Axes, t: F64, err: F64, sigma: F64 | None, label: str, unit: str = "m") -> None:
    """An error component against time with its ±3σ envelope."""
    idx = decimate(t.size)
    (line,) = ax.plot(t[idx], err[idx], lw=0.9, label=f"{label} error")
    if sigma is not None:
        s = 3.0 * sigma[idx]
        ax.fill_between(t[idx], -s, s, color=line.get_color(), alpha=0.15, label=f"{label} ±3σ")
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_xlabel("t, s")
    ax.set_ylabel(f"error, {unit}")
    ax.legend(loc="upper right", ncol=2)


def nees_plot(ax: Axes, series: dict[str, tuple[F64, F64]], dof: int) -> None:
    """NEES samples per series against the two-sided 95 % χ²(dof) interval of one sample."""
    lo, hi = nees_band(dof)
    for name, (t, v) in series.items():
        idx = decimate(t.size)
        ax.plot(t[idx], v[idx], ".", ms=2.5, label=name)
    ax.axhspan(lo, hi, color="g", alpha=0.12, label=f"χ²({dof}) 95 % [{lo:.2g}, {hi:.2g}]")
    ax.axhline(dof, color="g", lw=0.7)
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(LogFormatter(labelOnlyBase=True))  # plain text, no mathtext: faster
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("t, s")
    ax.set_ylabel("NEES")
    ax.legend(loc="upper right", ncol=3)


def standard_figures(
    series: list[ErrorSeries],
    *,
    plan_truths: dict[str, F64],
    plan_estimates: dict[str, tuple[F64, F64 | None]],
    points: dict[str, F64] | None = None,
    axes_names: tuple[str, str] = ("east", "north"),
    what: str = "",
) -> tuple[list[Figure], dict[str, Any]]:
    """Plan view, horizontal error components with ±3σ, NEES with its χ² band; plus their headline numbers."""
    figs: list[Figure] = []
    fig, ax = new_figure(height=5.0, width=7.5)
    plan_view(ax[0][0], plan_truths, plan_estimates, points=points)
    figs.append(render(fig, f"Plan view{what}", "truth (lines) and estimates (dots, 3σ ellipses)", left_in=0.9))
    head: dict[str, Any] = {}
    usable = [s for s in series if s.t_s.size]
    if not usable:
        return figs, head
    fig, axs = new_figure(rows=len(axes_names), height=2.4)
    for c, name in enumerate(axes_names):
        ax = axs[c][0]
        for s in usable:
            sig = None if s.cov is None else np.sqrt(np.clip(s.cov[:, c, c], 0.0, None))
            error_plot(ax, s.t_s, s.err[:, c], sig, s.name if len(usable) > 1 else name)
        ax.set_title(f"{name} error against truth" + (" (per platform)" if len(usable) > 1 else ""))
    figs.append(render(fig, f"Error against time{what}", "estimate − truth per axis, shaded: ±3σ of the filter"))
    with_cov = [s for s in usable if s.cov is not None]
    if with_cov:
        dof = with_cov[0].dims
        fig, ax = new_figure(height=3.0)
        nees_plot(ax[0][0], {s.name: (s.t_s, s.nees()) for s in with_cov if s.dims == dof}, dof)
        ax[0][0].set_title(f"NEES ({dof}-D position)")
        figs.append(render(fig, f"NEES{what}", "per sample; band: two-sided 95 % interval of one χ² sample"))
        all_nees = np.concatenate([s.nees() for s in with_cov if s.dims == dof])
        head["nees_dof"] = dof
        head["nees_mean"] = r(float(np.nanmean(all_nees))) if np.isfinite(all_nees).any() else None
        head["nees_in_95_band"] = r(in_band_fraction(all_nees, dof))
    herr = np.concatenate([s.horizontal_error() for s in usable])
    head["horizontal_error_rms_m"] = r(rms(herr))
    head["horizontal_error_max_m"] = r(float(np.max(herr))) if herr.size else None
    return figs, head


__all__ = [
    "MAX_ELLIPSES",
    "MAX_POINTS",
    "ErrorSeries",
    "Figure",
    "RunData",
    "Section",
    "cov_ellipse",
    "decimate",
    "error_plot",
    "error_series",
    "in_band_fraction",
    "nees",
    "nees_band",
    "nees_plot",
    "new_figure",
    "plan_view",
    "r",
    "render",
    "rms",
    "standard_figures",
]
