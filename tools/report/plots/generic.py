"""Any other publisher of positions: the common ``Fix`` and ``Track`` models (``schemas/outputs.py``).

A service without a section of its own (no ``Plugin.report``) gets the standard figures — plan view, error with
±3σ, NEES — for its ``Fix`` messages (against the truth of their ``platform``) and its ``Track`` s (plan view
only: a track has no platform to compare with).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from schemas import Fix, Track
from shared.foxglove.frames import Estimate, estimates_of

from . import own_section_services
from .common import RunData, Section, error_series, standard_figures


def build(data: RunData, metrics: dict[str, dict[str, Any]]) -> list[Section]:
    out = []
    known = own_section_services()
    for src in sorted(data.outputs):
        service = src.split("/", 1)[0]
        if service in known:
            continue
        msgs = [(ev.key, ev.msg) for ev in data.outputs[src] if isinstance(ev.msg, Fix | Track)]
        if msgs:
            out.append(_section(data, src, msgs))
    return out


def _section(data: RunData, src: str, msgs: list[tuple[str, Any]]) -> Section:
    service, _, instance = src.partition("/")
    sec = Section(service, instance, f"{service} — {instance}")
    by_entity: dict[str, list[Estimate]] = {}
    for key, m in msgs:
        for e in estimates_of(key, m, data.ctx):
            if e.kind in ("fix", "track"):
                by_entity.setdefault(e.entity, []).append(e)
    series = []
    plan: dict[str, tuple[Any, Any]] = {}
    truths: dict[str, Any] = {}
    for ent, ests in by_entity.items():
        plan[ent] = (np.array([e.position[:2] for e in ests]), None)
        platform = ests[0].platform
        if platform is not None and platform in data.truth:
            truths[platform] = data.truth[platform].pos[:, :2]
            s = error_series(ent, [e for e in ests if e.valid], data.truth[platform])
            if s is not None:
                series.append(s)
    figs, head = standard_figures(series, plan_truths=truths, plan_estimates=plan)
    sec.figures += figs
    sec.headline = {"messages": len(msgs), **head}
    return sec
