"""pcl_tracker (digest 003): confirmed tracks against the targets, track lifetimes and OSPA.

Per instance (one receiver–illuminator pair, ``PclScanReport`` per scan): every scan's confirmed tracks are
matched to the live targets (least total distance within ``match_distance_m``, as the mc plugin does); each
target's matched track gives an error series (east, north with ±3σ of its ``estimate``) and a 3-D NEES. The story:
each track's lifetime (tentative, confirmed, dropped; labelled with the target it followed) and the OSPA
distance per scan (the mc plugin's figures when the scenario is known, else computed the same way). Headline:
confirmed tracks, OSPA mean, steady-state position and velocity RMSE (second half of the run), id swaps and
false tracks (plugin), NEES.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from schemas.pcl_tracker import PclScanReport
from services.pcl_tracker.metrics import match_tracks, ospa

from .common import ErrorSeries, RunData, Section, new_figure, r, render, rms, standard_figures

KIND = "pcl_tracker"
MAX_ERROR_PANELS = 6


def build(data: RunData, metrics: dict[str, dict[str, Any]]) -> list[Section]:
    return [_section(data, src, metrics.get(src.split("/", 1)[1])) for src in data.sources(KIND)]


def _params(data: RunData, instance: str) -> dict[str, Any]:
    if data.scenario is None:
        return {}
    for est in data.scenario.estimators:
        if est.kind == KIND and est.instance == instance:
            from services.pcl_tracker.settings import PclTrackerParams, to_config

            p = PclTrackerParams.model_validate(dict(est.params))
            return {
                "match_distance_m": p.match_distance_m,
                "ospa_c_m": p.ospa_c_m,
                "ospa_p": p.ospa_p,
                "tx": list(to_config(p).geometry.tx_position_enu_m),
            }
    return {}


def _section(data: RunData, source: str, entry: dict[str, Any] | None) -> Section:
    instance = source.split("/", 1)[1]
    reports = [ev.msg for ev in data.outputs[source] if isinstance(ev.msg, PclScanReport)]
    scans = [rep for rep in reports if rep.trigger == "scan"]
    pair = f"{reports[0].receiver_id} / {reports[0].illuminator_id}" if reports else "?"
    sec = Section(KIND, instance, f"PCL tracker — {instance} (receiver / illuminator {pair})")
    par = _params(data, instance)
    m = entry.get("metrics") if entry else None
    match_d = float(par.get("match_distance_m", 2000.0))
    targets = list(m["targets"]) if m else _guess_targets(data, scans, match_d)
    # per scan: confirmed tracks matched to the live targets
    per_target: dict[str, list[tuple[float, Any, Any, Any, Any]]] = {t: [] for t in targets}
    track_target: dict[int, str] = {}
    ospa_t: list[float] = []
    ospa_c, ospa_p = float(par.get("ospa_c_m", 1000.0)), float(par.get("ospa_p", 2.0))
    scan_t = np.array([rep.header.stamp_ns / 1e9 for rep in scans], dtype=np.float64)
    known = [name for name in targets if name in data.truth]
    tpos = {name: data.truth[name].at(scan_t) for name in known}
    tvel = {name: data.truth[name].vel_at_many(scan_t) for name in known}
    own_ospa = not (m and m.get("ospa_m"))
    matched: set[tuple[int, int]] = set()  # (scan index, track id) of the confirmed tracks matched to a target
    for k, rep in enumerate(scans):
        t = float(scan_t[k])
        conf = [tr for tr in rep.tracks if tr.status == "CONFIRMED"]
        alive = [name for name in known if np.all(np.isfinite(tpos[name][k]))]
        tp = np.array([tr.estimate.mean[:3] for tr in conf], dtype=np.float64).reshape(-1, 3)
        gp = np.array([tpos[name][k] for name in alive], dtype=np.float64).reshape(-1, 3)
        if own_ospa:
            ospa_t.append(ospa(tp, gp, ospa_c, ospa_p))
        for i, j in match_tracks(tp, gp, match_d):
            tr = conf[i]
            name = alive[j]
            matched.add((k, tr.track_id))
            track_target.setdefault(tr.track_id, name)
            v = tvel[name][k]
            truth_vel = v if np.all(np.isfinite(v)) else None
            per_target[name].append(
                (
                    t,
                    np.asarray(tr.estimate.mean, dtype=np.float64),
                    gp[j],
                    np.asarray(tr.estimate.covariance, dtype=np.float64),
                    truth_vel,
                )
            )
    series: list[ErrorSeries] = []
    vel_err: list[tuple[float, float]] = []
    for name, rows in per_target.items():
        if not rows:
            continue
        est = np.array([row[1][:3] for row in rows])
        series.append(
            ErrorSeries(
                name,
                np.array([row[0] for row in rows]),
                est,
                np.array([row[2] for row in rows]),
                np.array([row[3][:3, :3] for row in rows]),
                horizontal_only=False,
            )
        )
        for row in rows:
            if row[4] is not None:
                vel_err.append((row[0], float(np.linalg.norm(row[1][3:] - row[4]))))
    truths = {n: data.truth[n].pos[:, :2] for n in targets if n in data.truth}
    # confirmed tracks: per target they followed (its colour, its panel), and those matched to none
    plan: dict[str, tuple[Any, Any]] = {
        name: (np.array([row[1][:2] for row in rows]), np.array([row[3][:3, :3] for row in rows]))
        for name, rows in per_target.items()
        if rows
    }
    unmatched = [
        (np.asarray(tr.estimate.mean[:2]), np.asarray(tr.estimate.covariance)[:3, :3])
        for k, rep in enumerate(scans)
        for tr in rep.tracks
        if tr.status == "CONFIRMED" and (k, tr.track_id) not in matched
    ]
    if unmatched:
        plan["confirmed, matched to no target"] = (
            np.array([p for p, _ in unmatched]).reshape(-1, 2),
            np.array([c for _, c in unmatched]).reshape(-1, 3, 3),
        )
    points = {"receiver": np.zeros((1, 2))}
    if par.get("tx") is not None:
        points["illuminator"] = np.asarray([par["tx"][:2]], dtype=np.float64)
    # each target's panel zooms to where it was tracked (a target flies on for hundreds of km after)
    focus = {
        name: np.array([xy for row in rows for xy in (row[1][:2], row[2][:2])], dtype=np.float64)
        for name, rows in per_target.items()
        if rows
    }
    figs, head = standard_figures(
        series[:MAX_ERROR_PANELS], plan_truths=truths, plan_estimates=plan, points=points, plan_focus=focus
    )
    sec.figures += figs
    if len(series) > MAX_ERROR_PANELS:
        sec.notes.append(f"error panels drawn for the first {MAX_ERROR_PANELS} of {len(series)} targets")
    sec.figures.append(_story(scans, track_target, m, ospa_t))
    t_end = max((rep.header.stamp_ns / 1e9 for rep in scans), default=0.0)
    half = t_end / 2.0
    pos_late: Any = np.concatenate([np.linalg.norm(s.err[s.t_s >= half], axis=1) for s in series]) if series else []
    vel_late = [e for t, e in vel_err if t >= half]
    confirmed_ids = {tr.track_id for rep in scans for tr in rep.tracks if tr.status == "CONFIRMED"}
    sec.headline = {
        "scans": len(scans),
        "confirmed_tracks": len(confirmed_ids),
        "targets": len(targets),
        "ospa_mean_m": r(
            float(np.mean(m["ospa_m"])) if m and m.get("ospa_m") else (float(np.mean(ospa_t)) if ospa_t else None)
        ),
        "pos_rmse_second_half_m": r(rms(pos_late)),
        "vel_rmse_second_half_mps": r(rms(vel_late)),
        **{k: v for k, v in head.items() if k.startswith("nees")},
    }
    if m:
        sec.headline.update({"id_swaps": m.get("id_swaps"), "false_confirmed_tracks": m.get("false_confirmed_tracks")})
    if not targets:
        sec.notes.append("no target truth found for this pair: no errors, NEES or OSPA against truth")
    return sec


def _guess_targets(data: RunData, scans: list[PclScanReport], match_d: float) -> list[str]:
    """Without the scenario: truth platforms some confirmed track came within ``match_d`` of."""
    found: list[str] = []
    for rep in scans[:: max(1, len(scans) // 50)]:
        t = np.array([rep.header.stamp_ns / 1e9])
        pts = [np.asarray(tr.estimate.mean[:3]) for tr in rep.tracks if tr.status == "CONFIRMED"]
        for name, ts in data.truth.items():
            p = ts.at(t)[0]
            if name not in found and np.all(np.isfinite(p)) and any(np.linalg.norm(q - p) <= match_d for q in pts):
                found.append(name)
    return found


def _story(
    scans: list[PclScanReport], track_target: dict[int, str], m: dict[str, Any] | None, ospa_t: list[float]
) -> Any:
    fig, axs = new_figure(rows=2, height=2.8)
    ax = axs[0][0]
    life: dict[int, dict[str, float]] = {}
    for rep in scans:
        t = rep.header.stamp_ns / 1e9
        for tr in rep.tracks:
            d = life.setdefault(tr.track_id, {"start": t, "end": t})
            d["end"] = t
            if tr.status == "CONFIRMED" and "confirmed" not in d:
                d["confirmed"] = t
    ids = sorted(life)
    shown = ids if len(ids) <= 80 else [i for i in ids if "confirmed" in life[i]][:80]
    for row, tid in enumerate(shown):
        d = life[tid]
        ax.plot([d["start"], d.get("confirmed", d["end"])], [row, row], color="0.7", lw=3)
        if "confirmed" in d:
            ax.plot([d["confirmed"], d["end"]], [row, row], color="tab:blue", lw=3)
            ax.annotate(track_target.get(tid, "false?"), (d["end"], row), xytext=(3, -3), textcoords="offset points")
    ax.set_yticks(range(len(shown)), [str(t) for t in shown], fontsize=9 if len(shown) <= 30 else 6)
    ax.set_ylabel("track id")
    ax.set_xlabel("t, s")
    ax.set_title("track lifetimes (grey: tentative, blue: confirmed; label: target followed)")
    ax = axs[1][0]
    if m and m.get("ospa_m") and m.get("t_s"):
        ax.plot(m["t_s"], m["ospa_m"], lw=1.0, label="OSPA (mc plugin)")
    elif ospa_t:
        ax.plot([rep.header.stamp_ns / 1e9 for rep in scans], ospa_t, lw=1.0, label="OSPA")
    ax.set_xlabel("t, s")
    ax.set_ylabel("OSPA, m")
    ax.set_title("OSPA distance between confirmed tracks and live targets, per scan")
    ax.legend(loc="upper right")
    return render(fig, "Track lifetimes and OSPA", "")
