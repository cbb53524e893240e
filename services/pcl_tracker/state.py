"""What a PCL tracker keeps (digest 003 §5.4): tracks, first-plot candidates, and one scan's bookkeeping.

The components (:mod:`.predictor`, :mod:`.associator`, :mod:`.updater`, :mod:`.initiator`, :mod:`.deleter`)
read and write :class:`TrackState`; the tracker loop (:mod:`.core`) records what happened to each track in a
:class:`ScanWork`, from which :mod:`.reports` builds the scan's report.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from shared.filters.covariance import CholeskyStats
from shared.filters.unscented import TransformResult

from .geometry import FloatArray


@dataclass
class TrackState:
    """Everything kept per track (digest §5.4). ``x``/``P`` are x_a (phase "ukf") or x_b (phase "bkf").

    With the IMM (``motion_model: imm``) ``x``/``P`` are the moment-matched combination of the model-matched
    estimates ``xm`` (r, 6), ``Pm`` (r, 6, 6) with probabilities ``mu`` (r,) (:mod:`.imm`); else those are None.
    """

    track_id: int
    status: str
    phase: str
    x: FloatArray
    P: FloatArray
    t_ns: int
    created_scan: int
    hits: int = 2
    misses: int = 0
    mn_hits: int = 0
    mn_scans: int = 0
    mu: FloatArray | None = None
    xm: FloatArray | None = None
    Pm: FloatArray | None = None

    def to_dict(self) -> dict[str, Any]:
        """Plain data (arrays as lists) for a snapshot."""
        d = dict(self.__dict__)
        for k in TRACK_ARRAYS:
            v = getattr(self, k)
            d[k] = None if v is None else v.tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrackState:
        arrays = {k: None if d.get(k) is None else np.array(d[k], dtype=np.float64) for k in TRACK_ARRAYS}
        return cls(**{**d, **arrays})


#: numpy fields of a TrackState (lists in a snapshot)
TRACK_ARRAYS = ("x", "P", "mu", "xm", "Pm")


@dataclass
class CandidateSet:
    """First plots awaiting a partner (digest §5.4), as arrays; kept in (scan_id, plot_id) order."""

    plot_id: list[str]
    scan_id: NDArray[np.int64]  # (C,)
    t_ns: NDArray[np.int64]  # (C,)
    z: FloatArray  # (C, 4) [r_b, a, e, v_b]
    sig: FloatArray  # (C, 4)
    zc: FloatArray  # (C, 3) converted position
    Rc: FloatArray  # (C, 3, 3)

    @classmethod
    def empty(cls) -> CandidateSet:
        return cls([], np.zeros(0, np.int64), np.zeros(0, np.int64), *(np.zeros((0, *d)) for d in _CAND_DIMS))

    def __len__(self) -> int:
        return len(self.plot_id)

    def take(self, idx: NDArray[np.int64]) -> CandidateSet:
        return CandidateSet(
            [self.plot_id[i] for i in idx.tolist()],
            self.scan_id[idx],
            self.t_ns[idx],
            self.z[idx],
            self.sig[idx],
            self.zc[idx],
            self.Rc[idx],
        )

    def extend(self, other: CandidateSet) -> CandidateSet:
        return CandidateSet(
            self.plot_id + other.plot_id,
            *(np.concatenate([getattr(self, k), getattr(other, k)]) for k in _CAND_ARRAYS),
        )

    def to_list(self) -> list[dict[str, Any]]:
        """Plain data, one dict per candidate, for a snapshot."""
        return [
            {
                "plot_id": self.plot_id[i],
                "scan_id": int(self.scan_id[i]),
                "t_ns": int(self.t_ns[i]),
                **{k: getattr(self, k)[i].tolist() for k in ("z", "sig", "zc", "Rc")},
            }
            for i in range(len(self))
        ]

    @classmethod
    def from_list(cls, cd: list[dict[str, Any]]) -> CandidateSet:
        if not cd:
            return cls.empty()
        return cls(
            [d["plot_id"] for d in cd],
            np.array([d["scan_id"] for d in cd], dtype=np.int64),
            np.array([d["t_ns"] for d in cd], dtype=np.int64),
            *(np.array([d[k] for d in cd], dtype=np.float64) for k in ("z", "sig", "zc", "Rc")),
        )


_CAND_ARRAYS = ("scan_id", "t_ns", "z", "sig", "zc", "Rc")
_CAND_DIMS = ((4,), (4,), (3,), (3, 3))


@dataclass
class ScanWork:
    """Per-scan bookkeeping used to build the report."""

    flags: list[str] = field(default_factory=list)
    #: tracks dropped in this scan, frozen at the drop: (track, reason, row of its image in ``pred``)
    dropping: list[tuple[TrackState, str, int | None]] = field(default_factory=list)
    assoc: dict[int, tuple[str, float]] = field(default_factory=dict)
    in_gate: dict[int, int] = field(default_factory=dict)
    track_flags: dict[int, list[str]] = field(default_factory=dict)
    updated: set[int] = field(default_factory=set)
    created: set[int] = field(default_factory=set)
    drops: Counter[str] = field(default_factory=Counter)
    #: the predicted bistatic images of this scan's live tracks (one batch) ...
    pred: TransformResult | None = None
    #: ... and, per track id, the row whose image is its output (x(k|k) = x(k|k-1) when not updated)
    images: dict[int, int] = field(default_factory=dict)
    chol: CholeskyStats = field(default_factory=CholeskyStats)
    #: IMM: every model's predicted measurement (n, r, 4) and covariance (n, r, 4, 4), rows as ``pred``
    model_images: tuple[FloatArray, FloatArray] | None = None
