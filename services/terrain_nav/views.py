"""terrain_nav's outputs as Foxglove estimates (``Plugin.views``; :mod:`shared.foxglove.frames`).

A ``TerrainFix`` is the corrected position in the map frame (x north, z east, h up) with its horizontal
covariance ``cov_xz_m2`` (rows x, z) and the vertical variance ``cov_vert[1][1]``; the vehicle is the fourth
chunk of its key ``fixstream/fix/terrain/<vehicle>``.
"""

from __future__ import annotations

from schemas.terrain_nav import TerrainFix
from shared.foxglove.frames import Estimate, FrameContext, cov2_enu


def terrain_fix(key: str, msg: TerrainFix, ctx: FrameContext) -> list[Estimate]:
    vehicle = key.split("/")[3] if key.count("/") >= 3 else "terrain"
    pos = ctx.to_enu([msg.x_corr_m, msg.z_corr_m, msg.h_corr_m], "map")
    cov = cov2_enu(msg.cov_xz_m2, north_first=True)  # (x north, z east)
    cov[2, 2] = max(float(msg.cov_vert[1][1]), 0.0)
    return [
        Estimate(
            "fix",
            vehicle,
            vehicle,
            msg.header.stamp_ns,
            pos,
            cov,
            True,
            label=f"fix ({msg.i_star},{msg.j_star})",
            extra={"dx_m": msg.dx_m, "dz_m": msg.dz_m, "dh_m": msg.dh_m},
        )
    ]


__all__ = ["terrain_fix"]
