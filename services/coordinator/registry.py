"""Vehicle registry of the base coordinator (digest §2.2, §7.3 S7)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.floating[Any]]

#: states in which a vehicle is a stationary beacon (AT_BASE only if configured)
DOCKED_STATES = ("DOCKED_SERVICING", "DOCKED_DONE")


@dataclass
class VehicleRecord:
    auv_id: str
    state: str = "UNKNOWN"  # UNKNOWN, AT_BASE, TRANSIT, DOCKED_SERVICING, DOCKED_DONE, GRANTED, FAULT
    node_id: str | None = None
    position: F64 | None = None  # NED m (node position when docked; last report when moving)
    last_heard_s: float = 0.0
    route: list[F64] = field(default_factory=list)
    speed_mps: float | None = None
    t_route_s: float = 0.0


def route_points(rec: VehicleRecord, t: float, horizon_s: float, spacing_m: float, depth_m: float) -> list[F64]:
    """Points along a moving AUV's planned route over the horizon, from its last known position."""
    pts: list[F64] = []
    start = rec.position if rec.position is not None else (rec.route[0] if rec.route else None)
    if start is None:
        return pts
    cur = np.array([start[0], start[1], depth_m])
    pts.append(cur.copy())
    speed = rec.speed_mps or 1.5
    budget = speed * horizon_s
    for wp in rec.route:
        nxt = np.array([wp[0], wp[1], depth_m])
        seg = float(np.linalg.norm(nxt[:2] - cur[:2]))
        if seg <= 1e-6:
            continue
        n = max(1, int(np.ceil(min(seg, budget) / spacing_m)))
        for i in range(1, n + 1):
            f = min(i * spacing_m, seg, budget) / seg
            pts.append(cur + f * (nxt - cur))
        budget -= seg
        if budget <= 0:
            break
        cur = nxt
    return pts
