"""lbl_nav's outputs as Foxglove estimates (``Plugin.views``; :mod:`shared.foxglove.frames`).

An ``LblFix`` is in (east, north, depth): the fix when valid, and its hypotheses (valid while the ambiguity is
not resolved).
"""

from __future__ import annotations

import numpy as np

from schemas.lbl_nav import LblFix
from shared.foxglove.frames import Estimate, FrameContext


def lbl_fix(key: str, msg: LblFix, ctx: FrameContext) -> list[Estimate]:
    out: list[Estimate] = []
    if msg.valid and msg.position_m is not None and msg.position_cov_m2 is not None:
        cov = ctx.cov_to_enu(np.asarray(msg.position_cov_m2, dtype=np.float64), "", axes="en_depth")
        pos = ctx.to_enu(msg.position_m, "", axes="en_depth")
        out.append(Estimate("fix", msg.platform, msg.platform, msg.header.stamp_ns, pos, cov, True, label=msg.status))
    for h in msg.hypotheses:
        out.append(
            Estimate(
                "hypothesis",
                f"{msg.platform}/h{h.hypothesis_id}",
                msg.platform,
                msg.header.stamp_ns,
                ctx.to_enu(h.position_m, "", axes="en_depth"),
                ctx.cov_to_enu(np.asarray(h.position_cov_m2, dtype=np.float64), "", axes="en_depth"),
                not msg.valid,
                label=f"h{h.hypothesis_id} p={h.probability:.3f}",
                extra={"probability": h.probability, "hypothesis_id": h.hypothesis_id},
            )
        )
    return out


__all__ = ["lbl_fix"]
