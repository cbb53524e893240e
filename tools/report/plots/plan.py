"""Plan views (east, north in metres) that stay readable whatever the scene: the whole scene, and each track zoomed.

A scene can be 50 km across (a radar, a receiver and five aircraft) while one track is 200 m long and its errors a
few metres: one panel of the whole scene shows that track as a dot. So the figure has

* an **overview** of everything (truth tracks, estimates, fixed points: beacons, receiver, radar), and
* one **panel per truth track** (up to :data:`MAX_TRACK_PANELS`), its limits the extent of that track and of the
  estimates that belong to it (:func:`owner_of`), padded — whatever else is in the scene.

When the scene is hardly larger than its one track, the overview alone is drawn, large. Axes keep equal scales
(metres are metres both ways) unless a track is more than :data:`MAX_ASPECT` times longer one way than the other;
then the panel says "not to scale". Lines are decimated per panel to what is inside it, so a zoomed panel of a
long recording keeps its detail; 3σ covariance ellipses are drawn for at most :data:`~.common.MAX_ELLIPSES`
estimates per panel, those inside it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure as MplFigure
from matplotlib.ticker import FuncFormatter

from shared.foxglove.frames import F64

from .common import FIG_WIDTH_IN, MAX_ELLIPSES, MAX_POINTS, Figure, apply_margins, cov_ellipse, decimate, render

MAX_TRACK_PANELS = 6
#: the least half-width of a zoomed panel (a vehicle standing still still gets a readable panel)
MIN_HALF_SPAN_M = 20.0
#: padding around a track, as a share of its span
PAD = 0.08
#: beyond this ratio of the two spans a panel is drawn not to scale
MAX_ASPECT = 6.0
#: an overview is drawn beside a single track only if the scene is this much larger than the track
OVERVIEW_RATIO = 1.6
#: panels wider than this are labelled in km
KM_ABOVE_M = 20_000.0


@dataclass(frozen=True)
class Box:
    """An axis-aligned extent in metres."""

    x0: float
    x1: float
    y0: float
    y1: float

    @staticmethod
    def of(xy: F64, robust: bool = False) -> Box | None:
        """The extent of the finite rows of ``xy`` (n, 2); ``robust``: the 0.5–99.5 % quantiles (a few wild
        estimates do not decide the zoom) when there are 200 points or more."""
        p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        p = p[np.all(np.isfinite(p), axis=1)]
        if p.size == 0:
            return None
        if robust and len(p) >= 200:
            lo, hi = np.quantile(p, [0.005, 0.995], axis=0)
        else:
            lo, hi = p.min(axis=0), p.max(axis=0)
        return Box(float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))

    def union(self, other: Box | None) -> Box:
        if other is None:
            return self
        return Box(min(self.x0, other.x0), max(self.x1, other.x1), min(self.y0, other.y0), max(self.y1, other.y1))

    @property
    def spans(self) -> tuple[float, float]:
        return self.x1 - self.x0, self.y1 - self.y0

    @property
    def diag(self) -> float:
        return math.hypot(*self.spans)

    def padded(self) -> Box:
        """The box with :data:`PAD` of its span on every side, at least :data:`MIN_HALF_SPAN_M` half-wide."""
        cx, cy = (self.x0 + self.x1) / 2, (self.y0 + self.y1) / 2
        big = max(self.spans)
        hx = max(self.spans[0] * (0.5 + PAD), big * PAD, MIN_HALF_SPAN_M)
        hy = max(self.spans[1] * (0.5 + PAD), big * PAD, MIN_HALF_SPAN_M)
        return Box(cx - hx, cx + hx, cy - hy, cy + hy)

    def inside(self, xy: F64, grow: float = 1.0) -> np.ndarray:
        """Which rows of ``xy`` lie inside the box grown ``grow`` times about its centre."""
        cx, cy = (self.x0 + self.x1) / 2, (self.y0 + self.y1) / 2
        hx, hy = self.spans[0] / 2 * grow, self.spans[1] / 2 * grow
        return np.asarray((np.abs(xy[:, 0] - cx) <= hx) & (np.abs(xy[:, 1] - cy) <= hy))


def owner_of(estimate: str, truths: list[str]) -> str | None:
    """The truth track an estimate series belongs to: its name, or a name that starts with it (``tan1 fixes``)."""
    if estimate in truths:
        return estimate
    return next((t for t in truths if estimate.startswith(f"{t} ") or estimate.startswith(f"{t}/")), None)


def _visible(xy: F64, box: Box | None) -> F64:
    """The part of a line inside ``box`` (grown 1.5×, so lines leave the panel at its edge), decimated, with NaN
    where it leaves and comes back (no chord across the panel)."""
    if box is None:
        return xy[decimate(len(xy))]
    inside = np.flatnonzero(box.inside(xy, 1.5))
    if inside.size == 0:
        return np.zeros((0, 2))
    idx = inside[decimate(inside.size)]
    stride = max(1, math.ceil(inside.size / MAX_POINTS))
    gaps = np.flatnonzero(np.diff(idx) > 2 * stride)
    out = xy[idx]
    return np.insert(out, gaps + 1, np.nan, axis=0) if gaps.size else out


def _panel(
    ax: Axes,
    truths: dict[str, F64],
    estimates: dict[str, tuple[F64, F64 | None]],
    points: dict[str, F64],
    colors: dict[str, str],
    box: Box | None,
    title: str,
    size_in: tuple[float, float],
    own: str | None = None,
) -> None:
    """One panel; ``own``: the track it is about — the other tracks and their estimates are drawn faint grey,
    without ellipses, so a panel shows its own track even where tracks cross."""
    names = list(truths)

    def other(series: str) -> bool:
        owner = owner_of(series, names)
        return own is not None and owner is not None and owner != own

    for name, xy in truths.items():
        v = _visible(xy, box)
        faint = other(name)
        ax.plot(
            v[:, 0],
            v[:, 1],
            "-",
            color="0.8" if faint else colors[name],
            lw=0.8 if faint else 1.4,
            label=f"{name} truth",
            zorder=1 if faint else 3,
        )
    shown = [(n, xy, c) for n, (xy, c) in estimates.items() if len(xy)]
    per_series = max(1, MAX_ELLIPSES // max(1, sum(1 for n, _, _ in shown if not other(n))))
    for name, xy, covs in shown:
        v = _visible(xy, box)
        faint = other(name)
        ax.plot(
            v[:, 0],
            v[:, 1],
            ".",
            ms=2.0 if faint else 3.5,
            color="0.8" if faint else colors[name],
            alpha=0.85,
            label=f"{name} estimate",
            zorder=1 if faint else 2,
        )
        if faint or covs is None or not len(covs):
            continue
        idx = np.flatnonzero(box.inside(xy) if box is not None else np.ones(len(xy), dtype=bool))
        for k in idx[:: max(1, idx.size // per_series)] if idx.size else []:
            ax.add_patch(cov_ellipse(xy[k], covs[k][:2, :2], color=colors[name], lw=0.8, alpha=0.6))
    for name, xy in points.items():
        ax.plot(xy[:, 0], xy[:, 1], "k^", ms=8)
        ax.annotate(name, (float(xy[0, 0]), float(xy[0, 1])), xytext=(4, 4), textcoords="offset points")
    ax.set_xlabel("east, m")
    ax.set_ylabel("north, m")
    ax.ticklabel_format(useOffset=False, style="plain")
    if box is not None:
        b = box.padded()
        wide, high = b.spans
        if max(wide, high) / max(min(wide, high), 1e-9) > MAX_ASPECT:
            title += "\n(not to scale)"
        else:  # equal scales: widen the short side to the panel's own shape
            pos = ax.get_position()
            fw, fh = size_in
            shape = (pos.width * fw) / max(pos.height * fh, 1e-9)
            cx, cy = (b.x0 + b.x1) / 2, (b.y0 + b.y1) / 2
            wide, high = max(wide, high * shape), max(high, wide / shape)
            b = Box(cx - wide / 2, cx + wide / 2, cy - high / 2, cy + high / 2)
        ax.set_xlim(b.x0, b.x1)
        ax.set_ylim(b.y0, b.y1)
    else:
        ax.set_aspect("equal", adjustable="datalim")
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    if max(x1 - x0, y1 - y0) > KM_ABOVE_M:  # tens of km: tick labels in km, short enough not to collide
        km = FuncFormatter(lambda v, _: f"{v / 1000:g}")
        ax.xaxis.set_major_formatter(km)
        ax.yaxis.set_major_formatter(km)
        ax.set_xlabel("east, km")
        ax.set_ylabel("north, km")
    ax.set_title(title)


def plan_figure(
    truths: dict[str, F64],
    estimates: dict[str, tuple[F64, F64 | None]],
    points: dict[str, F64] | None = None,
    *,
    title: str = "Plan view",
    focus: dict[str, F64] | None = None,
) -> Figure:
    """The overview and one zoomed panel per truth track (module doc); truth lines, estimate dots, 3σ ellipses.
    ``focus``: per track, the points its panel zooms to instead of the whole truth (e.g. where it was tracked)."""
    fig, _, caption, margins = plan_axes(truths, estimates, points, focus)
    return render(fig, title, caption, **margins)


def plan_axes(
    truths: dict[str, F64],
    estimates: dict[str, tuple[F64, F64 | None]],
    points: dict[str, F64] | None = None,
    focus: dict[str, F64] | None = None,
) -> tuple[MplFigure, list[tuple[Axes, Box | None]], str, dict[str, float]]:
    """The plan figure drawn but not rendered: (figure, its panels with the track box each zooms to — None for
    the overview —, caption, the margins to render it with)."""
    points = points or {}
    focus = focus or {}
    names = [t for t, xy in truths.items() if len(xy)]
    palette = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colors: dict[str, str] = {t: palette[i % len(palette)] for i, t in enumerate(names)}
    k = len(names)
    for e in estimates:
        owner = owner_of(e, names)
        if owner is not None and e != owner:
            colors[e] = colors[owner]
        elif e not in colors:
            colors[e] = palette[k % len(palette)]
            k += 1
    boxes: dict[str, Box] = {}
    for t in names[:MAX_TRACK_PANELS]:
        box = Box.of(focus[t]) if t in focus and len(focus[t]) else None
        box = box or Box.of(truths[t])
        if box is None:  # no finite point
            continue
        for e, (xy, _) in estimates.items():
            if owner_of(e, names) == t and len(xy):
                box = box.union(Box.of(xy, robust=True))
        boxes[t] = box
    scene: Box | None = None
    for xy in [*truths.values(), *(xy for xy, _ in estimates.values()), *points.values()]:
        b = Box.of(xy, robust=True)
        scene = b if scene is None else scene.union(b) if b is not None else scene
    panels: list[tuple[Box | None, str, str | None]] = []
    if len(boxes) == 1 and scene is not None and scene.diag <= OVERVIEW_RATIO * next(iter(boxes.values())).diag:
        panels.append((scene, "the whole scene", None))
    else:
        panels.append((None, "the whole scene", None))
        for t, box in boxes.items():
            w, h = box.spans
            panels.append((box, f"{t}: its track, {_km(w)} × {_km(h)}", t))
    n = len(panels)
    cols = 1 if n == 1 else 2 if n in (2, 4) else 3
    rows = math.ceil(n / cols)
    side = FIG_WIDTH_IN / cols
    height = side * (0.62 if n == 1 else 0.92)
    entries = len(names) + sum(1 for xy, _ in estimates.values() if len(xy))  # legend entries
    margins = {"left_in": 1.0, "bottom_in": 0.65 + 0.28 * math.ceil(entries / 4), "hspace_in": 0.75}
    fig_h = height * rows + margins["bottom_in"]
    fig, axs = plt.subplots(rows, cols, figsize=(FIG_WIDTH_IN, fig_h), squeeze=False)
    apply_margins(fig, **margins)  # before drawing: the zoomed panels fit their limits to their shape
    drawn: list[tuple[Axes, Box | None]] = []
    for i, (box, ptitle, own) in enumerate(panels):
        ax = axs[i // cols][i % cols]
        _panel(ax, truths, estimates, points, colors, box, ptitle, (FIG_WIDTH_IN, fig_h), own)
        drawn.append((ax, box))
    for j in range(n, rows * cols):
        axs[j // cols][j % cols].set_visible(False)
    handles, labels = axs[0][0].get_legend_handles_labels()
    if labels:
        fig.legend(handles, labels, loc="lower center", ncol=min(4, len(labels)), frameon=False, markerscale=2)
    caption = "truth: lines; estimates: dots with 3σ covariance ellipses (every k-th); ▲ fixed points"
    if len(panels) > 1:
        caption += "; a track's own panel shows the other tracks faint grey"
    if focus:
        caption += " and zooms to where the track was estimated"
    if len(names) > MAX_TRACK_PANELS:
        caption += f"; zoomed panels for the first {MAX_TRACK_PANELS} of {len(names)} tracks"
    return fig, drawn, caption, margins


def _km(metres: float) -> str:
    if metres >= 2000:
        return f"{metres / 1000:.3g} km"
    return f"{metres:.0f} m" if metres >= 100 else f"{metres:.3g} m"


__all__ = ["MAX_TRACK_PANELS", "Box", "owner_of", "plan_axes", "plan_figure"]
