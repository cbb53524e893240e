"""One late arrival (digest §4.11 [E]): use a gated cycle without the one arrival that explains its residual.

Multipath only delays. With the innovation e = d - h(x_hat) (M,) and its covariance S, a late follower j raises
only its own d_j (direction g = u_j, the j-th unit vector), a late leader lowers every d_j equally (g = -1). For
each hypothesis g the delay estimate and the share of the NIS it explains are

    b = g^T S^-1 e / g^T S^-1 g ,        z = (g^T S^-1 e)^2 / g^T S^-1 g ,        NIS = e^T S^-1 e

and g explains the cycle if b > b_min (a delay, not an advance), z alone fails the 1-D gate chi2_1 and the rest
NIS - z passes the (M-1)-D gate chi2_{M-1}. The largest such z wins; the cycle is then used through a transform T
with T g = 0 (follower j: the other followers; leader: the leader-free differences d_j - d_2).

:class:`LateArrivalRescue` adds the policy: not the same arrival twice in a row (multipath is random; a repeated
one points at the filter, not at the arrival).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import F64


@dataclass(frozen=True)
class LateArrival:
    """The arrival that explains a residual: its id, T with T g = 0, and the reduced NIS (NIS - z)."""

    arrival_id: str
    T: F64
    nis_rest: float


def one_late_arrival(
    e: F64, S: F64, ids: list[str], gate_1: float, rest_gates: dict[int, float], min_delay_m: float = 0.0
) -> LateArrival | None:
    """The late arrival that explains e (module docstring), or None. ``ids``: leader first, then the M followers;
    ``gate_1`` the 1-D gate chi2_1, ``rest_gates[m]`` the m-D gate for the rest (m <= 16)."""
    M = e.size
    Si_e = np.linalg.solve(S, e)
    nis = float(e @ Si_e)
    best: tuple[float, int] | None = None
    for k in range(M + 1):  # k < M: follower k; k == M: the leader
        g = -np.ones(M) if k == M else np.eye(M)[k]
        Si_g = np.linalg.solve(S, g)
        num, den = float(g @ Si_e), float(g @ Si_g)
        z = num * num / den
        passes = num > min_delay_m * den and z > gate_1 and nis - z <= rest_gates[min(M - 1, 16)]
        if passes and (best is None or z > best[0]):
            best = (z, k)
    if best is None:
        return None
    z, k = best
    if k == M:
        T = np.column_stack([-np.ones(M - 1), np.eye(M - 1)])  # d_j - d_2: leader-free differences
        return LateArrival(ids[0], T, nis - z)
    T = np.delete(np.eye(M), k, axis=0)  # the other followers
    return LateArrival(ids[1 + k], T, nis - z)


class LateArrivalRescue:
    """The rescue policy: one late arrival, not the same one as in the last used cycle."""

    def __init__(self, gates: dict[int, float]) -> None:
        self.gates = gates  # chi2_{m, gate_probability}, m = 1..16
        self.last_dropped: str | None = None

    def explain(self, e: F64, S: F64, ids: list[str]) -> LateArrival | None:
        """One late arrival explains e at the filter's gates, and it is not the one dropped last time."""
        late = one_late_arrival(e, S, ids, self.gates[1], self.gates)
        if late is not None and late.arrival_id == self.last_dropped:
            return None  # multipath is random: the same arrival late twice in a row points at the filter
        return late

    def remember(self, dropped: str | None) -> None:
        """The arrival dropped from the last cycle that passed the cycle checks (None: none, or not used)."""
        self.last_dropped = dropped

    def clear(self) -> None:
        self.last_dropped = None
