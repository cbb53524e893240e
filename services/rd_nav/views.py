"""rd_nav's outputs as Foxglove estimates (``Plugin.views``; :mod:`shared.foxglove.frames`).

An ``RdNavFix`` is horizontal: ``position_ned_m`` with the 2x2 ``cov_xy_m2`` (rows x north, y east); its vertical
variance is the nominal one.
"""

from __future__ import annotations

from schemas.rd_nav import RdNavFix
from shared.foxglove.frames import Estimate, FrameContext, cov2_enu


def rd_fix(key: str, msg: RdNavFix, ctx: FrameContext) -> list[Estimate]:
    pos = ctx.to_enu(msg.position_ned_m, "", axes="ned")
    cov = cov2_enu(msg.cov_xy_m2, north_first=True)  # (x north, y east)
    return [
        Estimate(
            "fix",
            msg.auv_id,
            msg.auv_id,
            msg.header.stamp_ns,
            pos,
            cov,
            msg.valid,
            horizontal_only=True,
            label=f"{msg.estimator} {msg.status}",
            extra={"estimator": msg.estimator, "kind": msg.kind, "cycle_status": msg.cycle_status},
        )
    ]


__all__ = ["rd_fix"]
