"""rd_nav's outputs as Foxglove estimates (``Plugin.views``; :mod:`shared.foxglove.frames`).

An ``RdNavFix`` is horizontal: its block holds x (north), y (east) and their 2x2 covariance; the vertical is the
pressure depth ``depth_m`` with the nominal variance.
"""

from __future__ import annotations

from schemas.rd_nav import RdNavFix
from shared.foxglove.frames import NOMINAL_VERTICAL_VAR_M2, Estimate, FrameContext, gaussian_position


def rd_fix(key: str, msg: RdNavFix, ctx: FrameContext) -> list[Estimate]:
    got = gaussian_position(msg.estimate, ctx, vertical=(msg.depth_m, NOMINAL_VERTICAL_VAR_M2))
    if got is None:
        return []
    pos, cov, horizontal = got
    return [
        Estimate(
            "fix",
            msg.auv_id,
            msg.auv_id,
            msg.header.stamp_ns,
            pos,
            cov,
            msg.valid,
            horizontal_only=horizontal,
            label=f"{msg.estimator} {msg.status}",
            extra={"estimator": msg.estimator, "kind": msg.kind, "cycle_status": msg.cycle_status},
        )
    ]


__all__ = ["rd_fix"]
