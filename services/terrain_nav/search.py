"""The recurrent search as a component of the navigator: what the two algorithm variants share and promise.

:class:`~.core.TerrainNavigator` is the front end (synchronisation of INS, radio altimeter and baro, the
rejection rules, resets, the output messages); the search it is given turns synchronised samples into
:class:`~.evaluation.Evaluation` records. Two searches exist:

* :class:`~.modified_algorithm.ModifiedSearch` (the default, digest §2): cell-rate conversion, groups of N_p,
  the segmented window of N_s, C1-C4, the fix with its cell-centre terms (and the refinement of ``robust``);
* :class:`~.base_algorithm.BaseSearch` (digest §2.13, the A/B reference): bilinear map reads per sample,
  N_p = N_s = 1, C1 only, the bare offset.

Both build their search over :class:`SearchContext`, the parts the navigator computes once from the map and
the configuration.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from .config import TerrainNavConfig
from .evaluation import Evaluation
from .filter import KalmanBank
from .geometry import HypothesisGrid
from .maps import ReferenceMap
from .window import SegmentedWindow


@dataclass(frozen=True)
class SearchContext:
    """What a search is built from: the map, the configuration, the hypothesis grid and the navigator's counters."""

    map: ReferenceMap
    cfg: TerrainNavConfig
    grid: HypothesisGrid
    zone: NDArray[np.bool_]  # cells whose (2 M_x + 1) x (2 M_z + 1) hypothesis patch fits the map
    D1: float  # map-error variance term (m^2)
    L_zk: float  # the C2 reference level (m^2)
    counters: Counter[str]  # shared with the navigator: one set of counts per service


class RecurrentSearch(Protocol):
    """A recurrent search over the hypothesis grid, fed one synchronised sample at a time."""

    N_min: int
    N_max: int
    bank: KalmanBank
    window: SegmentedWindow[Any]
    total_meas: int
    n_evaluations: int

    def clear(self) -> None:
        """Forget the window, the KF states and every run-time memory (a reset); keep the map."""

    def push_sample(
        self,
        t: float,
        x: float,
        z: float,
        h_ins: float,
        h_ra: float,
        valid: bool = True,
        v_ground: float = 0.0,
        vh: float | None = None,
    ) -> list[Evaluation]:
        """One synchronised sample ``(t, x_ins, z_ins, h_ins, h_ra)`` (plus ground and vertical speed)."""
        ...


class OutOfZone:
    """The OUT_OF_ZONE verdicts of a search whose INS position left the correction zone: at most one per
    ``period_s`` of data time (``out_of_zone_period_s``), whatever the sample rate; :meth:`reset` with the search."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.last_t: float | None = None

    def reset(self) -> None:
        self.last_t = None

    def at(self, t: float) -> list[Evaluation]:
        """The verdict to emit for an out-of-zone sample at ``t`` s (none within ``period_s`` of the last)."""
        if self.last_t is None or t - self.last_t >= self.period_s:
            self.last_t = t
            return [Evaluation(t=t, state="OUT_OF_ZONE", detail="INS position outside the correction zone")]
        return []


#: how a navigator builds its search
SearchFactory = Callable[[SearchContext], RecurrentSearch]
