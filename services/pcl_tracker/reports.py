"""The PCL tracker's output messages: :class:`~schemas.pcl_tracker.PclTrackReport` per track and one
:class:`~schemas.pcl_tracker.PclScanReport` per processed scan (digest 003 §5.3, §5.5 step 6).

Every report message is built here. A track's output (two Gaussian blocks, ``estimate`` and ``bistatic``) is
x(k|k), P(k|k) in ENU and its bistatic image
z_b(k|k) = E[h_b(x_a(k|k))] by the inverse UT (n = 6) — reused from the prediction when the track was not
updated (x(k|k) = x(k|k-1)) — or H_b x_b for a bistatic ("bkf") track, whose ENU output is the UT of x_b
through h_a^(6). Angles are reported in degrees. The reports are built with :func:`shared.models.built` from arrays
checked here (finite; covariances symmetrised), which is what pydantic's validation would check at about
0.1 ms per report; consumers validate on decode.
"""

from __future__ import annotations

import math
from typing import Any, TypeVar

import numpy as np
from pydantic import BaseModel

from schemas.base import Header
from schemas.pcl_tracker import BISTATIC, PclScanReport, PclTrackReport
from shared.estimates import CV_STATE, gaussian
from shared.filters.covariance import symmetrize
from shared.models import built

from .config import PclTrackerConfig
from .filter import bistatic_image, bkf_measurement
from .geometry import FloatArray
from .initiation import bistatic_to_cartesian
from .plots import NormalisedPlots
from .state import ScanWork, TrackState

_DEG = 180.0 / math.pi
_BISTATIC_UNITS = np.array([1.0, _DEG, _DEG, 1.0])


class ReportBuilder:
    """Builds the reports of one receiver–illuminator pair from the tracks and a scan's :class:`ScanWork`."""

    def __init__(self, config: PclTrackerConfig) -> None:
        geo = config.geometry
        self.frame_id = geo.frame_id
        self.receiver_id = geo.receiver_id
        self.illuminator_id = geo.illuminator_id
        self.transform = config.tracker.transform
        self.gamma4 = config.tracker.gamma4

    def track_reports(
        self,
        trs: list[TrackState],
        sid: int,
        t_ns: int,
        work: ScanWork,
        images: list[int | None] | None,
        tx: FloatArray,
        drop_reasons: list[str] | None = None,
    ) -> list[PclTrackReport]:
        """Reports for tracks, batched; ``images`` are rows of reusable images in ``work.pred`` (else the UT
        of x(k|k) is computed). With ``drop_reasons`` the reports are the tracks' final DROPPED reports."""
        n = len(trs)
        if n == 0:
            return []
        imgs: list[int | None] = list(images) if images is not None else [None] * n
        X = np.stack([t.x for t in trs])
        P = np.stack([t.P for t in trs])
        Z = np.empty((n, 4))
        PZ = np.empty((n, 4, 4))
        need = [k for k in range(n) if imgs[k] is None or trs[k].phase == "bkf"]
        have = [k for k in range(n) if imgs[k] is not None and trs[k].phase != "bkf"]
        if have:
            assert work.pred is not None
            rows = np.array([imgs[k] for k in have], dtype=np.int64)
            Z[have], PZ[have] = work.pred.mean[rows], work.pred.cov[rows]
        for phase in ("ukf", "bkf"):
            idx = [k for k in need if trs[k].phase == phase]
            if not idx:
                continue
            if phase == "ukf":
                res = bistatic_image(X[idx], P[idx], tx, self.transform, work.chol, with_cross=False)
            else:
                res = bkf_measurement(X[idx], P[idx])
                ca = bistatic_to_cartesian(X[idx], P[idx], tx, self.transform, work.chol)
                X[idx], P[idx] = ca.mean, ca.cov
            Z[idx], PZ[idx] = res.mean, res.cov
        Z = Z * _BISTATIC_UNITS
        PZ = symmetrize(PZ * np.outer(_BISTATIC_UNITS, _BISTATIC_UNITS))
        P = symmetrize(P)
        if not (np.isfinite(X).all() and np.isfinite(P).all() and np.isfinite(Z).all() and np.isfinite(PZ).all()):
            raise RuntimeError(f"non-finite track state in scan {sid}")
        X_l, P_l, Z_l, PZ_l = X.tolist(), P.tolist(), Z.tolist(), PZ.tolist()
        frame, bistatic_frame = self.frame_id, f"bistatic/{self.receiver_id}/{self.illuminator_id}"
        out = []
        t_s = t_ns * 1e-9
        assoc_of, flags_of, in_gate_of = work.assoc.get, work.track_flags.get, work.in_gate.get
        created, updated = work.created, work.updated
        for k, tr in enumerate(trs):
            tid = tr.track_id
            assoc = assoc_of(tid)
            flags = list(flags_of(tid, ()))
            if tid in created:
                flags.append("initiated")
            if assoc is None:
                flags.append("coasted")
                nis = None
            else:
                nis = None if math.isnan(assoc[1]) else max(assoc[1], 0.0)
            drop = drop_reasons[k] if drop_reasons is not None else None
            tentative = tr.status == "TENTATIVE" and drop is None
            out.append(
                built(
                    PclTrackReport,
                    {
                        "track_id": tid,
                        "status": "DROPPED" if drop is not None else tr.status,
                        "scan_id": sid,
                        "t_s": t_s,
                        "estimate": gaussian(frame, CV_STATE, X_l[k], P_l[k], validate=False),
                        "bistatic": gaussian(bistatic_frame, BISTATIC, Z_l[k], PZ_l[k], validate=False),
                        "associated_plot_id": None if assoc is None else assoc[0],
                        "nis": nis,
                        "n_plots_in_gate": in_gate_of(tid, 0),
                        "coasted": assoc is None,
                        "updated": tid in updated,
                        "hits": tr.hits,
                        "consecutive_misses": tr.misses,
                        "age_scans": max(sid - tr.created_scan, 0),
                        "created_scan_id": tr.created_scan,
                        "confirm_progress": [tr.mn_hits, tr.mn_scans] if tentative else None,
                        "filter_phase": tr.phase,
                        "model_probabilities": None if tr.mu is None else tr.mu.tolist(),
                        "drop_reason": drop,
                        "flags": flags,
                    },
                )
            )
        return out

    def scan_report(
        self,
        live: list[TrackState],
        n_candidates: int,
        sid: int,
        t_ns: int,
        work: ScanWork,
        plots: NormalisedPlots | None,
        tx: FloatArray,
        trigger: str,
        extra: dict[str, Any] | None = None,
    ) -> PclScanReport:
        """The scan's report: every live track (``live``, by track id) and the final reports of the dropped ones."""
        finals = self.track_reports(
            [d[0] for d in work.dropping],
            sid,
            t_ns,
            work,
            [d[2] for d in work.dropping],
            tx,
            [d[1] for d in work.dropping],
        )
        images: list[int | None] = [work.images.get(t.track_id) for t in live]
        reports = self.track_reports(live, sid, t_ns, work, images, tx) + finals
        reports.sort(key=lambda r: (r.track_id, r.status == "DROPPED"))
        nis = [max(v[1], 0.0) for tid, v in work.assoc.items() if not math.isnan(v[1])]
        n_plots_in = 0 if plots is None else len(plots) + sum(plots.rejected.values())
        values: dict[str, Any] = {
            "header": Header(stamp_ns=t_ns, frame_id=self.frame_id, source="pcl_tracker"),
            "receiver_id": self.receiver_id,
            "illuminator_id": self.illuminator_id,
            "scan_id": sid,
            "trigger": trigger,
            "t_s": t_ns * 1e-9,
            "tracks": reports,
            "n_plots_in": n_plots_in,
            "n_plots_rejected": dict(plots.rejected) if plots is not None else {},
            "n_plots_flagged": dict(plots.flagged) if plots is not None else {},
            "n_associated": 0,
            "n_initiated": 0,
            "n_candidates": n_candidates,
            "n_tentative": sum(1 for t in live if t.status == "TENTATIVE"),
            "n_confirmed": sum(1 for t in live if t.status == "CONFIRMED"),
            "n_dropped": len(finals),
            "n_coasting": sum(1 for t in live if t.track_id not in work.assoc),
            "gap_scans": 0,
            "mean_nis": float(np.mean(nis)) if nis else None,
            "gate_d2": self.gamma4,
            "n_cholesky_fallbacks": work.chol.total,
            "n_sigma_clamped": 0,
            "flags": list(dict.fromkeys(work.flags)),
        }
        values.update(extra or {})
        # the track reports are checked in track_reports; validating them again here would cost ~1.5 µs each
        return built(PclScanReport, values)


_M = TypeVar("_M", bound=BaseModel)
