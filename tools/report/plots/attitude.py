"""attitude (digest 004): heading, pitch and roll of every target against truth, per radar site.

Per instance (``attitude/<site>``, estimates on ``fixstream/fix/attitude/<site>/<target>``): plan view of the
targets (truth, filtered positions with 3σ ellipses of the ``estimate`` block's position, the radar), the
error of the line-of-sight angles ψᴸ, ϑᴸ, γᴸ — the paper's metric (§3.3) — against time with the filter's ±3σ,
the 3-D position NEES, and the angles ψ, ϑ, γ (earth frame) against the true ones. Errors are computed as the
mc plugin computes them (:class:`services.attitude.metrics.RunRecorder`: wrapped estimate − truth at the truth
sample of the same stamp, truth moved to the radar frame). Headline: LOS-angle RMS from scan 40 on (the
paper's "units of degrees after ~40 contacts"), scans per target, NEES.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from schemas.attitude import AttitudeEstimate
from services.attitude.mc import is_realtime, radar_frame_truth
from services.attitude.metrics import RunRecorder
from shared.foxglove.frames import estimates_of

from .common import (
    RunData,
    Section,
    decimate,
    error_series,
    new_figure,
    r,
    render,
    rms,
    robust_limit,
    standard_figures,
)

KIND = "attitude"
LOS = (("psi_los", "ψᴸ heading"), ("theta_los", "ϑᴸ pitch"), ("gamma_los", "γᴸ roll"))
#: the paper's "after ~40 contacts"
FROM_SCAN = 40
#: targets (rows) of the per-target figures, at most
MAX_TARGET_ROWS = 6


def build(data: RunData, metrics: dict[str, dict[str, Any]]) -> list[Section]:
    return [_section(data, src, metrics.get(src.split("/", 1)[1])) for src in data.sources(KIND)]


def _section(data: RunData, source: str, entry: dict[str, Any] | None) -> Section:
    instance = source.split("/", 1)[1]
    # the real-time stream only: a site run with smoother_lag_scans also publishes SMOOTHED estimates of past plots
    ests = [
        (ev.key, ev.msg) for ev in data.outputs[source] if isinstance(ev.msg, AttitudeEstimate) and is_realtime(ev.msg)
    ]
    site = ests[0][1].site_id if ests else instance
    sec = Section(KIND, instance, f"Aircraft attitude from radar plots — site {site}")
    site_pos = data.ctx.sites.get(site)
    if site_pos is None:
        sec.notes.append(f"position of radar site {site} unknown (no scenario): taken at the origin")
        site_pos = [0.0, 0.0, 0.0]
    by_target: dict[str, list[AttitudeEstimate]] = {}
    for _, m in ests:
        if m.status != "COASTING":
            by_target.setdefault(m.target_id, []).append(m)
    records: dict[str, dict[str, Any]] = {}
    # the mc plugin's per-target records are exactly these errors (same code): reuse them when computed
    pm: dict[str, Any] | None = entry.get("metrics") if entry else None
    planned: dict[str, dict[str, Any]] = dict(pm["targets"]) if pm and pm.get("site_id") == site else {}
    series = []
    plan: dict[str, tuple[Any, Any]] = {}
    for tid, msgs in by_target.items():
        truth = data.truth.get(tid)
        pos_est = [e for (key, m) in ests if m.target_id == tid for e in estimates_of(key, m, data.ctx)]
        s = error_series(tid, pos_est, truth, horizontal_only=False)
        if s is not None:
            series.append(s)
        if pos_est:
            covs = [e.cov for e in pos_est]
            plan[tid] = (
                np.array([e.position[:2] for e in pos_est]),
                np.array(covs) if all(c is not None for c in covs) else None,
            )
        records[tid] = planned.get(tid) or _record(data, tid, msgs, site_pos)
    truths = {t: data.truth[t].pos[:, :2] for t in by_target if t in data.truth}
    figs, head = standard_figures(
        series, plan_truths=truths, plan_estimates=plan, points={f"radar {site}": np.array([site_pos[:2]])}
    )
    # the standard error figure is the position error; the paper's metric is the LOS angles: add them
    sec.figures += figs
    sec.figures.append(_los_errors(records))
    sec.figures.append(_angles(data, by_target))
    pooled: dict[str, list[float]] = {name: [] for name, _ in LOS}
    scans = {tid: len(rec["stamp_ns"]) for tid, rec in records.items()}
    first = (
        FROM_SCAN if max(scans.values(), default=0) >= FROM_SCAN + 5 else max(1, max(scans.values(), default=0) // 2)
    )
    for rec in records.values():
        for name, _ in LOS:
            pooled[name] += [v for v in rec["err"][name][first - 1 :] if v is not None and math.isfinite(v)]
    sec.headline = {
        "targets": len(by_target),
        "estimates": len(ests),
        "scans_per_target_max": max(scans.values(), default=0),
        f"los_rms_deg_from_scan_{first}": {name: r(rms(v)) for name, v in pooled.items()},
        **{k: v for k, v in head.items() if k.startswith("nees")},
        "position_error_rms_m": head.get("horizontal_error_rms_m"),
    }
    return sec


def _record(data: RunData, tid: str, msgs: list[AttitudeEstimate], site_pos: list[float]) -> dict[str, Any]:
    """The mc plugin's per-target record (errors at every truth sample of the target)."""
    by_stamp = {m.header.stamp_ns: m for m in msgs}
    rec = RunRecorder()
    truths = [ev.msg for ev in data.events_on(f"fixstream/truth/{tid}")]
    for tr in truths:
        rec.add(by_stamp.get(tr.header.stamp_ns), radar_frame_truth(tr, site_pos))  # type: ignore[arg-type]
    return rec.rec


def _los_errors(records: dict[str, dict[str, Any]]) -> Any:
    """One row per target (its own ±3σ band), one column per LOS angle."""
    shown = list(records.items())[:MAX_TARGET_ROWS]
    fig, axs = new_figure(rows=len(shown), cols=3, height=1.9)
    palette = [f"C{i}" for i in range(10)]
    clipped = False
    for row, (tid, rec) in enumerate(shown):
        t = np.array(rec["stamp_ns"], dtype=np.float64) / 1e9
        for col, (name, label) in enumerate(LOS):
            ax = axs[row][col]
            e = np.array([np.nan if v is None else v for v in rec["err"][name]], dtype=np.float64)
            s = np.array([np.nan if v is None else v for v in rec["sigma"][name]], dtype=np.float64)
            idx = decimate(t.size)
            color = palette[row % len(palette)]
            ax.plot(t[idx], e[idx], lw=1.0, color=color)
            ax.fill_between(t[idx], -3 * s[idx], 3 * s[idx], color=color, alpha=0.18, lw=0)
            ax.axhline(0.0, color="k", lw=0.6)
            lim = min(robust_limit([e], [s]) or 60.0, 60.0)
            ax.set_ylim(-lim, lim)
            clipped |= bool(np.nanmax(np.abs(np.concatenate([e, 3 * s])), initial=0.0) > lim)
            ax.set_title(f"{tid}: {label} error")
            ax.set_ylabel("error, deg")
            ax.set_xlabel("t, s")
    caption = "the paper's metric (§3.3): wrapped estimate − truth per scan; shaded: ±3σ reported by the filter"
    if clipped:
        caption += "; y axes clipped (at most ±60°)"
    if len(records) > len(shown):
        caption += f"; the first {len(shown)} of {len(records)} targets"
    return render(fig, "LOS angle errors against time, per target", caption, hspace_in=0.9)


def _angles(data: RunData, by_target: dict[str, list[AttitudeEstimate]]) -> Any:
    """One row per target, one column per earth-frame angle: estimates (dots) and truth (line)."""
    shown = list(by_target.items())[:MAX_TARGET_ROWS]
    fig, axs = new_figure(rows=len(shown), cols=3, height=1.9)
    for row, (tid, msgs) in enumerate(shown):
        c = f"C{row % 10}"
        t = np.array([m.header.stamp_ns / 1e9 for m in msgs])
        ts = data.truth.get(tid)
        for col, (field, idx_true, label) in enumerate(
            (("psi_deg", 0, "heading ψ"), ("theta_deg", 1, "pitch ϑ"), ("gamma_deg", 2, "roll γ"))
        ):
            ax = axs[row][col]
            v = np.array([np.nan if getattr(m, field) is None else getattr(m, field) for m in msgs], dtype=np.float64)
            k = decimate(t.size)
            ax.plot(t[k], v[k], ".", ms=4, color=c)
            if ts is not None and ts.attitude_rad is not None:
                deg = np.degrees(ts.attitude_rad[:, idx_true])
                j = decimate(ts.t_s.size)
                tt, dd = ts.t_s[j], deg[j]
                if idx_true == 0:  # heading in [0, 360): no vertical line where it wraps
                    dd = np.mod(dd, 360.0)
                    wraps = np.flatnonzero(np.abs(np.diff(dd)) > 180.0) + 1
                    tt, dd = np.insert(tt, wraps, np.nan), np.insert(dd, wraps, np.nan)
                ax.plot(tt, dd, "-", lw=1.0, color="0.25")
            ax.set_title(f"{tid}: {label}")
            ax.set_ylabel("deg")
            ax.set_xlabel("t, s")
    caption = "earth-frame angles: estimates (dots), truth (grey line)"
    if len(by_target) > len(shown):
        caption += f"; the first {len(shown)} of {len(by_target)} targets"
    return render(fig, "Attitude angles against truth, per target", caption, hspace_in=0.9)
