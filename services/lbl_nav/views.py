"""lbl_nav's outputs as Foxglove estimates (``Plugin.views``; :mod:`shared.foxglove.frames`).

An ``LblFix`` is in (east, north, depth): the fix when valid, and its hypotheses (valid while the ambiguity is
not resolved); their blocks are read by :func:`~shared.foxglove.frames.gaussian_position`.
"""

from __future__ import annotations

from schemas.lbl_nav import LblFix
from shared.foxglove.frames import Estimate, FrameContext, gaussian_position, hypothesis_estimates


def lbl_fix(key: str, msg: LblFix, ctx: FrameContext) -> list[Estimate]:
    out: list[Estimate] = []
    got = gaussian_position(msg.estimate, ctx) if msg.valid and msg.estimate is not None else None
    if got is not None:
        out.append(
            Estimate("fix", msg.platform, msg.platform, msg.header.stamp_ns, got[0], got[1], True, label=msg.status)
        )
    out.extend(hypothesis_estimates(msg.platform, msg.header.stamp_ns, msg.hypotheses, ctx, not msg.valid))
    return out


__all__ = ["lbl_fix"]
