"""terrain_nav's outputs as Foxglove estimates (``Plugin.views``; :mod:`shared.foxglove.frames`).

A ``TerrainFix`` is the corrected horizontal position (block ``estimate``, map frame: x north, z east) placed at
the corrected altitude ``h_corr_m`` with the variance of the altitude correction (``vertical``, component
``dh``); the vehicle is the fourth chunk of its key ``fixstream/fix/terrain/<vehicle>``.
"""

from __future__ import annotations

from schemas.terrain_nav import TerrainFix
from shared.foxglove.frames import Estimate, FrameContext, gaussian_position


def terrain_fix(key: str, msg: TerrainFix, ctx: FrameContext) -> list[Estimate]:
    vehicle = key.split("/")[3] if key.count("/") >= 3 else "terrain"
    v = msg.vertical
    dh = v.components.index("dh") if "dh" in v.components else len(v.mean) - 1
    got = gaussian_position(msg.estimate, ctx, vertical=(msg.h_corr_m, max(float(v.covariance[dh][dh]), 0.0)))
    if got is None:
        return []
    return [
        Estimate(
            "fix",
            vehicle,
            vehicle,
            msg.header.stamp_ns,
            got[0],
            got[1],
            True,
            label=f"fix ({msg.i_star},{msg.j_star})",
            extra={"dx_m": msg.dx_m, "dz_m": msg.dz_m, "dh_m": v.mean[dh]},
        )
    ]


__all__ = ["terrain_fix"]
