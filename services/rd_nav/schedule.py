"""RD-LBL cycle schedule (digest §4.9, [E]): reply delays, cycle period and a packet-overlap check.

Constraints for packet length T_pkt, guard g and followers ordered j = 2, 3, ...:

* tau_2 >= T_pkt + g (the leader's packet always arrives first, s >= 0);
* tau_{j+1} - tau_j >= (|r_1,j+1 - r_1j| + r_j,j+1) / c + T_pkt + g;
* T_c >= tau_last + (r_1,last + rho_max) / c + T_pkt + g.
"""

from __future__ import annotations

import numpy as np

from .geometry import F64, leader_follower_ranges


def min_reply_delays(
    leader: F64, followers: F64, t_pkt_s: float, guard_s: float, c_mps: float, tau_first_s: float | None = None
) -> list[float]:
    """Smallest reply delays satisfying the ordering constraints, s."""
    r1 = leader_follower_ranges(leader, followers)
    taus = [t_pkt_s + guard_s if tau_first_s is None else max(tau_first_s, t_pkt_s + guard_s)]
    for j in range(1, followers.shape[0]):
        rjj = float(np.linalg.norm(followers[j] - followers[j - 1]))
        taus.append(taus[-1] + (abs(r1[j] - r1[j - 1]) + rjj) / c_mps + t_pkt_s + guard_s)
    return taus


def min_cycle_period(
    leader: F64, followers: F64, tau_s: list[float], rho_max_m: float, t_pkt_s: float, guard_s: float, c_mps: float
) -> float:
    """Smallest T_c that lets every receiver within rho_max close its cycle before the next ping, s."""
    r1 = leader_follower_ranges(leader, followers)
    return max(t + (r + rho_max_m) / c_mps for t, r in zip(tau_s, r1, strict=True)) + t_pkt_s + guard_s


def arrival_starts(
    receivers: F64, leader: F64, followers: F64, tau_s: list[float], c_mps: float, period_s: float
) -> F64:
    """Start times of the packets at static receivers (P, 3) for one cycle emitted at t = 0, plus the next
    leader packet: columns leader, followers..., next leader (s)."""
    r1 = leader_follower_ranges(leader, followers)
    rho1 = np.linalg.norm(receivers - leader[None, :], axis=1)
    cols = [rho1 / c_mps]
    for j in range(followers.shape[0]):
        rhoj = np.linalg.norm(receivers - followers[j][None, :], axis=1)
        cols.append((r1[j] + rhoj) / c_mps + tau_s[j])
    cols.append(period_s + rho1 / c_mps)
    return np.column_stack(cols)


def overlapping(starts: F64, t_pkt_s: float, jitter_s: float = 0.0) -> np.ndarray:
    """True where any two packets of a row overlap at the receiver (each lasting T_pkt, +- emission jitter)."""
    s = np.sort(starts, axis=1)
    gaps = np.diff(s, axis=1)
    return np.asarray((gaps < t_pkt_s + jitter_s).any(axis=1))
