"""rd_nav + coordinator (digest 002): the group's fixes, the beacons' roles and what happened to each cycle.

One section for the group: every ``rd_nav/<vehicle>`` instance (``RdNavFix``; the particle filter's cycle
fixes are scored, ``kind = CYCLE``, ``estimator = PF``) and the coordinator's ``BeaconAssignment`` s (from any
publisher, e.g. ``coordinator/<group>``, or the player when it feeds a fixed assignment). Plan view (every
moving AUV's truth and fixes with 3σ ellipses, the beacon nodes of the assignments), north/east errors with
±3σ of the ``estimate`` block, 2-D NEES, and the story: each vehicle's role over time (leader, follower, not a beacon)
and each moving AUV's cycle status (USED, PARTIAL, REJECTED, NONE). Headline per AUV: the paper's figures —
mean, SD and max of the per-coordinate error — and cycles by status.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from schemas.rd_nav import BeaconAssignment, RdNavFix
from shared.foxglove.frames import estimates_of

from .common import ErrorSeries, RunData, Section, error_series, new_figure, r, render, standard_figures

KIND = "rd_nav"
STATUSES = ["USED", "PARTIAL", "REJECTED", "NONE"]


def build(data: RunData, metrics: dict[str, dict[str, Any]]) -> list[Section]:
    sources = data.sources(KIND)
    if not sources:
        return []
    return [_section(data, sources, metrics)]


def assignments(data: RunData) -> list[BeaconAssignment]:
    """Every BeaconAssignment in the recording, by stamp."""
    found = [ev.msg for ev in data.events if isinstance(ev.msg, BeaconAssignment)]
    found += [ev.msg for out in data.outputs.values() for ev in out if isinstance(ev.msg, BeaconAssignment)]
    return sorted(found, key=lambda a: (a.header.stamp_ns, a.epoch))


def _section(data: RunData, sources: list[str], metrics: dict[str, dict[str, Any]]) -> Section:
    sec = Section(KIND, ",".join(s.split("/", 1)[1] for s in sources), "AUV group navigation (RD-LBL)")
    series: list[ErrorSeries] = []
    plan: dict[str, tuple[Any, Any]] = {}
    truths: dict[str, Any] = {}
    fixes_by_auv: dict[str, list[RdNavFix]] = {}
    per_auv: dict[str, Any] = {}
    for src in sources:
        fixes = [(ev.key, ev.msg) for ev in data.outputs[src] if isinstance(ev.msg, RdNavFix)]
        if not fixes:
            continue
        auv = fixes[0][1].auv_id
        cyc = [(k, f) for k, f in fixes if f.kind == "CYCLE" and f.estimator == "PF"]
        fixes_by_auv[auv] = [f for _, f in cyc]
        ests = [e for k, f in cyc for e in estimates_of(k, f, data.ctx)]
        truth = data.truth.get(auv)
        s = error_series(auv, ests, truth, horizontal_only=True)
        if truth is not None:
            truths[auv] = truth.pos[:, :2]
        if ests:
            plan[auv] = (np.array([e.position[:2] for e in ests]), np.array([e.cov for e in ests]))
        status = Counter(f.cycle_status for f in fixes_by_auv[auv])
        entry: dict[str, Any] = {"cycle_fixes": len(cyc), "cycles": dict(sorted(status.items()))}
        if s is not None:
            series.append(s)
            e = s.err[:, :2]
            entry.update(
                {
                    "error_mean_m": [r(float(v)) for v in e.mean(axis=0)],
                    "error_sd_m": [r(float(v)) for v in e.std(axis=0, ddof=1)] if len(e) > 1 else None,
                    "error_max_abs_m": r(float(np.max(np.abs(e)))),
                    "horizontal_rms_m": r(float(np.sqrt(np.mean(np.sum(e * e, axis=1))))),
                }
            )
        entry["reinit_count"] = max((f.reinit_count for f in fixes_by_auv[auv]), default=0)
        per_auv[auv] = entry
    assigns = assignments(data)
    nodes: dict[str, Any] = {}
    for a in assigns:
        for vid, p in zip([a.leader_id, *a.follower_ids], a.positions_ned_m, strict=False):
            nodes[vid] = np.array([data.ctx.to_enu(p, "", axes="ned")[:2]])
    figs, head = standard_figures(series, plan_truths=truths, plan_estimates=plan, points=nodes)
    sec.figures += figs
    sec.figures.append(_story(assigns, fixes_by_auv, data.t_end_s))
    sec.headline = {
        "moving_auvs": len(per_auv),
        "assignments": len(assigns),
        "role_changes": max(0, len({(a.leader_id, *a.follower_ids) for a in assigns}) - 1),
        **{k: v for k, v in head.items() if k.startswith("nees")},
        "per_auv": per_auv,
    }
    return sec


def _story(assigns: list[BeaconAssignment], fixes: dict[str, list[RdNavFix]], t_end: float) -> Any:
    fig, axs = new_figure(rows=2, height=2.6)
    ax = axs[0][0]
    ids = sorted({v for a in assigns for v in (a.leader_id, *a.follower_ids)} | set(fixes))
    for k, a in enumerate(assigns):
        t0 = a.header.stamp_ns / 1e9
        t1 = assigns[k + 1].header.stamp_ns / 1e9 if k + 1 < len(assigns) else max(t_end, t0)
        for vid in ids:
            row = ids.index(vid)
            if vid == a.leader_id:
                ax.plot([t0, t1], [row, row], color="tab:red", lw=5, solid_capstyle="butt")
            elif vid in a.follower_ids:
                ax.plot([t0, t1], [row, row], color="tab:blue", lw=5, solid_capstyle="butt")
    for vid in fixes:
        ts = [f.header.stamp_ns / 1e9 for f in fixes[vid]]
        if ts:
            ax.plot([min(ts), max(ts)], [ids.index(vid)] * 2, color="0.6", lw=2)
    ax.set_yticks(range(len(ids)), ids)
    ax.set_title("roles over time (red: leader, blue: follower, grey: moving, navigating)")
    ax.set_xlabel("t, s")
    ax = axs[1][0]
    auvs = sorted(fixes)
    colors = {"USED": "tab:green", "PARTIAL": "tab:olive", "REJECTED": "tab:red", "NONE": "0.6"}
    for row, auv in enumerate(auvs):
        fs = fixes[auv]
        for st in STATUSES:
            t = [f.header.stamp_ns / 1e9 for f in fs if f.cycle_status == st]
            if t:
                ax.scatter(t, [row] * len(t), s=8, marker="|", color=colors[st], label=st if row == 0 else None)
    ax.set_yticks(range(len(auvs)), auvs)
    ax.set_title("cycle status per moving AUV")
    ax.set_xlabel("t, s")
    if auvs:
        ax.legend(loc="upper right", ncol=4)
    return render(
        fig, "Beacon roles and cycle status", "from the coordinator's assignments and the fixes' cycle_status"
    )
