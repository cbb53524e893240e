"""The associator: gating in bistatic coordinates and plot-to-track assignment (digest 003 §2.6 steps 3–4).

For track i with predicted measurement z_b(k|k-1), R_b(k|k-1) (:mod:`.predictor`) and plot j with
z_b = [r_b, alpha, eps, v_b] and noise R_b = diag(sigma^2):

    nu = z_b - z_b(k|k-1)   (alpha wrapped to (-pi, pi]),   S = R_b(k|k-1) + R_b,
    d^2 = nu^T S^-1 nu,      the pair is gated if d^2 <= gamma_4 = chi^2_4(P_G)   (13.28 for P_G = 0.99).

With the IMM, a pair is gated if it is inside some model's gate (d^2 the least over the models).
Assignment over the gated pairs only, confirmed tracks first, then tentative tracks with the plots left
(§5.5 step 3): GNN minimises sum d^2 (or sum d^2 + ln det S with ``gnn_cost_logdet``) over one-to-one
assignments that use as many gated pairs as possible (:func:`.association.assign_pairs`); NN takes the
gated pair of least cost repeatedly. Ties break by track row, then plot_id (plots are sorted by id).
The d^2 reported for an assigned pair is against the track's own prediction (the IMM mixture for an IMM
track).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from shared.filters import kalman
from shared.filters.covariance import symmetrize

from .association import GatedPairs, IntArray, assign_pairs, gate_pairs, gate_pairs_models
from .config import TrackerConfig
from .filter import innovation
from .geometry import BoolArray, FloatArray
from .predictor import Prediction
from .state import TrackState


@dataclass
class Association:
    """What the associator decided for one scan (rows index the tracks, columns the plots)."""

    #: assigned (track row, plot row) pairs, in assignment order: confirmed tracks first, each group by row
    pairs: list[tuple[int, int]]
    #: d^2 of each assigned pair (against the track's own prediction)
    d2: dict[tuple[int, int], float]
    #: plots inside at least one gate (they never start tracks, §2.3)
    in_some_gate: BoolArray
    #: number of plots in each track's gate
    n_in_gate: IntArray


class Associator(Protocol):
    """Gates and assigns the plots ``z`` (P, 4), ``R_plot`` (P, 4, 4) to the predicted tracks."""

    def associate(
        self, tracks: list[TrackState], pred: Prediction, z: FloatArray, R_plot: FloatArray
    ) -> Association: ...


class GatedAssociator:
    """Gate at ``gamma`` (default gamma_4 from the configuration), then GNN or NN per status group (module doc)."""

    def __init__(self, config: TrackerConfig, method: str | None = None, gamma: float | None = None) -> None:
        self.method = config.association if method is None else method
        self.gamma = config.gamma4 if gamma is None else gamma
        self.cost_logdet = config.gnn_cost_logdet

    def gate(self, pred: Prediction, z: FloatArray, R_plot: FloatArray) -> GatedPairs:
        """The (track, plot) pairs with d^2 <= gamma, with d^2 and ln det S."""
        if not (len(pred.images.mean) and len(z)):
            return GatedPairs.empty()
        if pred.model_images is not None:  # IMM: the union of the models' gates, least d² over the models
            return gate_pairs_models(*pred.model_images, z, R_plot, self.gamma)
        return gate_pairs(pred.images.mean, pred.images.cov, z, R_plot, self.gamma)

    def associate(self, tracks: list[TrackState], pred: Prediction, z: FloatArray, R_plot: FloatArray) -> Association:
        n_plots = len(z)
        gp = self.gate(pred, z, R_plot)
        in_some_gate: BoolArray = np.zeros(n_plots, dtype=bool)
        in_some_gate[gp.plot] = True
        n_in_gate = np.bincount(gp.track, minlength=len(tracks))
        cost = gp.d2 + gp.logdet if self.cost_logdet else gp.d2
        pairs: list[tuple[int, int]] = []
        used = np.zeros(n_plots, dtype=bool)
        confirmed = np.array([tr.status == "CONFIRMED" for tr in tracks], dtype=bool)
        if len(gp):
            for group in (confirmed, ~confirmed):
                for r, c in assign_pairs(gp, cost, group, ~used, self.method):
                    pairs.append((r, c))
                    used[c] = True
        pair_d2 = {(int(a), int(b)): float(v) for a, b, v in zip(gp.track, gp.plot, gp.d2, strict=True)}
        if pred.model_images is not None and pairs:  # IMM: report d² against the track's (mixture) prediction
            ti = np.array([i for i, _ in pairs], dtype=np.int64)
            pj = np.array([c for _, c in pairs], dtype=np.int64)
            nu = innovation(z[pj], pred.images.mean[ti])
            d2_mix = kalman.nis(nu, symmetrize(pred.images.cov[ti] + R_plot[pj]))
            pair_d2.update({p: float(v) for p, v in zip(pairs, d2_mix.tolist(), strict=True)})
        return Association(pairs, pair_d2, in_some_gate, n_in_gate)
