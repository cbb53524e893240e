"""pcl_tracker's outputs as Foxglove estimates (``Plugin.views``; :mod:`shared.foxglove.frames`).

A ``PclScanReport`` carries every track of the scan: each one not ``DROPPED`` is an estimate (valid when
``CONFIRMED``) at the position of its ``estimate`` block, with the velocity components as an extra.
"""

from __future__ import annotations

import numpy as np

from schemas.pcl_tracker import PclScanReport
from shared.foxglove.frames import Estimate, FrameContext, gaussian_position


def scan_report(key: str, msg: PclScanReport, ctx: FrameContext) -> list[Estimate]:
    out = []
    for t in msg.tracks:
        got = None if t.status == "DROPPED" else gaussian_position(t.estimate, ctx)
        if got is None:
            continue
        out.append(
            Estimate(
                "track",
                f"track {t.track_id}",
                None,
                msg.header.stamp_ns,
                got[0],
                got[1],
                t.status == "CONFIRMED",
                label=f"{t.track_id} {t.status[0]}",
                extra={"track_id": t.track_id, "status": t.status, "velocity": np.asarray(t.estimate.mean[3:])},
            )
        )
    return out


__all__ = ["scan_report"]
