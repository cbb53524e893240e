"""pcl_tracker's outputs as Foxglove estimates (``Plugin.views``; :mod:`shared.foxglove.frames`).

A ``PclScanReport`` carries every track of the scan: each one not ``DROPPED`` is an estimate (valid when
``CONFIRMED``) at the first three components of ``state_enu`` with the top-left 3x3 of ``cov_enu``.
"""

from __future__ import annotations

import numpy as np

from schemas.pcl_tracker import PclScanReport
from shared.foxglove.frames import Estimate, FrameContext


def scan_report(key: str, msg: PclScanReport, ctx: FrameContext) -> list[Estimate]:
    f = msg.header.frame_id
    out = []
    for t in msg.tracks:
        if t.status == "DROPPED":
            continue
        cov = np.asarray(t.cov_enu, dtype=np.float64)[:3, :3]
        out.append(
            Estimate(
                "track",
                f"track {t.track_id}",
                None,
                msg.header.stamp_ns,
                ctx.to_enu(t.state_enu[:3], f),
                ctx.cov_to_enu(cov, f),
                t.status == "CONFIRMED",
                label=f"{t.track_id} {t.status[0]}",
                extra={"track_id": t.track_id, "status": t.status, "velocity": np.asarray(t.state_enu[3:])},
            )
        )
    return out


__all__ = ["scan_report"]
