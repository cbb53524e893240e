"""attitude's outputs as Foxglove estimates (``Plugin.views`` of services/attitude/plugin.py).

An ``AttitudeEstimate`` in the radar's NUE frame: position (x[0], x[3], x[6]) with the matching 3x3 block of
``state_cov``, valid when ``VALID``.
"""

from __future__ import annotations

import numpy as np

from schemas.attitude import AttitudeEstimate
from shared.foxglove.frames import Estimate, FrameContext


def attitude_estimate(key: str, msg: AttitudeEstimate, ctx: FrameContext) -> list[Estimate]:
    if msg.state is None:
        return []
    f = msg.header.frame_id
    x = msg.state
    pos = ctx.to_enu([x[0], x[3], x[6]], f)
    cov = None
    if msg.state_cov is not None:
        p = np.asarray(msg.state_cov, dtype=np.float64)[np.ix_([0, 3, 6], [0, 3, 6])]
        cov = ctx.cov_to_enu(p, f)
    label = f"{msg.target_id} ψ={msg.psi_deg:.0f}°" if msg.psi_deg is not None else msg.target_id
    return [
        Estimate("fix", msg.target_id, msg.target_id, msg.header.stamp_ns, pos, cov, msg.status == "VALID", label=label)
    ]


__all__ = ["attitude_estimate"]
