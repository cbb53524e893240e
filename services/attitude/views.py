"""attitude's outputs as Foxglove estimates (``Plugin.views`` of services/attitude/plugin.py).

An ``AttitudeEstimate`` in the radar's NUE frame: the position of its 9-state block (components x, y, z) with
their 3x3 covariance, valid when ``VALID``; labelled with the heading.
"""

from __future__ import annotations

from schemas.attitude import AttitudeEstimate
from shared.foxglove.frames import Estimate, FrameContext, gaussian_position


def attitude_estimate(key: str, msg: AttitudeEstimate, ctx: FrameContext) -> list[Estimate]:
    got = None if msg.estimate is None else gaussian_position(msg.estimate, ctx)
    if got is None:
        return []
    label = f"{msg.target_id} ψ={msg.psi_deg:.0f}°" if msg.psi_deg is not None else msg.target_id
    stamp = msg.header.stamp_ns
    return [Estimate("fix", msg.target_id, msg.target_id, stamp, got[0], got[1], msg.status == "VALID", label=label)]


__all__ = ["attitude_estimate"]
