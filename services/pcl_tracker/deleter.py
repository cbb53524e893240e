"""The confirmer (M/N) and the deleter (K misses, capacity) of the track life cycle (digest 003 §2.5, §2.7).

Confirmation, M/N [P] with the exact counting of §2.5 [R/D]: a track created from the plot pair on scans
(s_1, s_2) is TENTATIVE; its window is the N scans after s_2, in which it counts the scans h (``mn_hits``,
those with an associated plot) and n (``mn_scans``, all of them, gaps included). It is

* CONFIRMED as soon as h >= M (M = 0: confirmed at creation, no tentative stage);
* deleted ("MN_failed") as soon as M cannot be reached any more: h + (N - n) < M.

Deletion, K misses [P] (§2.7): a track is dropped at the K-th consecutive scan without an associated plot
("K_misses"); a hit resets the count; until then the extrapolation x(k|k) = x(k|k-1) is its output.
Capacity [D] (§5.1 limits): beyond ``max_tentative_tracks`` the weakest tentative tracks (fewest hits, then
oldest, then lowest id) are dropped ("capacity").

In the BKF + UKF scheme a confirmed bistatic track hands over to the Cartesian UKF: x_a, P_a = UT (n = 6) of
x_b, P_b through h_a^(6) (§2.5, :func:`.initiation.bistatic_to_cartesian`).
"""

from __future__ import annotations

from shared.filters.covariance import CholeskyStats

from .config import LimitsConfig, TrackerConfig
from .geometry import FloatArray
from .initiation import bistatic_to_cartesian
from .state import TrackState


class MofNConfirmer:
    """M/N confirmation (module doc); ``M``, ``N`` default to the configuration's ``confirm_M``, ``confirm_N``."""

    def __init__(self, config: TrackerConfig, M: int | None = None, N: int | None = None) -> None:
        self.M = config.confirm_M if M is None else M
        self.N = config.confirm_N if N is None else N
        self.handover = config.scheme == "bkf_ukf"
        self.transform = config.transform

    def hit(self, tr: TrackState, tx: FloatArray, chol: CholeskyStats | None) -> None:
        """An associated plot: count it (hits, M/N window), reset the misses, confirm at M hits."""
        tr.hits += 1
        tr.misses = 0
        if tr.status == "TENTATIVE":
            tr.mn_hits += 1
            tr.mn_scans += 1
            if tr.mn_hits >= self.M:
                self.confirm(tr, tx, chol)

    def miss(self, tr: TrackState, n: int = 1) -> None:
        """``n`` scans without a plot (a gap counts its missing scans)."""
        tr.misses += n
        if tr.status == "TENTATIVE":
            tr.mn_scans += n

    def failed(self, tr: TrackState) -> bool:
        """A tentative track that can no longer reach M hits in its window."""
        return tr.status == "TENTATIVE" and tr.mn_hits + (self.N - tr.mn_scans) < self.M

    def confirm(self, tr: TrackState, tx: FloatArray, chol: CholeskyStats | None) -> None:
        tr.status = "CONFIRMED"
        if tr.phase == "bkf" and self.handover:
            res = bistatic_to_cartesian(tr.x[None], tr.P[None], tx, self.transform, chol)
            tr.x, tr.P, tr.phase = res.mean[0], res.cov[0], "ukf"


class MissDeleter:
    """Drops a track at K consecutive misses, and the weakest tentative tracks beyond the capacity (module doc)."""

    def __init__(self, config: TrackerConfig, limits: LimitsConfig, K: int | None = None) -> None:
        self.K = config.drop_K if K is None else K
        self.max_tentative = limits.max_tentative_tracks

    def deletes(self, tr: TrackState) -> bool:
        return tr.misses >= self.K

    def over_capacity(self, tracks: list[TrackState]) -> list[TrackState]:
        """The tentative tracks to drop so that at most ``max_tentative_tracks`` remain."""
        tent = [t for t in tracks if t.status == "TENTATIVE"]
        excess = len(tent) - self.max_tentative
        if excess <= 0:
            return []
        tent.sort(key=lambda t: (t.hits, t.created_scan, t.track_id))
        return tent[:excess]
