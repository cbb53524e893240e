"""The updater: assigned tracks corrected with their plot (digest 003 §2.6 steps 5–6, §2.5 BKF).

The paper's update ("converted_position", phase "ukf"): the plot's (r_b, alpha, eps) is converted by the
UT (n = 3) through h_a^(3) to y_a(k), R_a(k) (:func:`.filter.convert_plots`, once per plot per scan), and
the linear KF with H = [I_3 0] gives

    K = P_a(k|k-1) H^T [H P_a(k|k-1) H^T + R_a(k)]^-1,
    x_a(k|k) = x_a(k|k-1) + K [y_a(k) - H x_a(k|k-1)],
    P_a(k|k) = (I - K H) P_a(k|k-1) (I - K H)^T + K R_a(k) K^T   (Joseph form, symmetrised)

(:func:`shared.filters.kalman.update`). v_b is not used in the update (§2.6). Variants:

* ``measurement_model: bistatic_ukf4`` [D]: the UKF update with the 4-D plot z_b and R_b,
  S = R_b(k|k-1) + R_b, K = P_xz S^-1, x = x + K nu (alpha wrapped), P = P - K S K^T;
* ``motion_model: imm`` [E]: each model-matched filter takes the KF update above with the same y_a, R_a,
  model probabilities mu_j ∝ Lambda_j c_j (Lambda_j from the converted position, or from the bistatic
  innovation with ``imm_likelihood: bistatic``), output their moment-matched mixture (:mod:`.imm`);
* phase "bkf" (§2.5): the linear KF of x_b with H_b selecting (r_b, alpha, eps, v_b), alpha wrapped.

A plot below ``rb_min_convertible_m`` (``low_rb``) or whose conversion failed is associated but does not
update a Cartesian track (flags ``low_rb_hit``, ``conversion_failed``); the track keeps x(k|k-1).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from shared.filters.unscented import TransformResult

from .config import TrackerConfig
from .filter import ConvertedPlots, bkf_update, kf_position_update, ukf_bistatic_update
from .geometry import FloatArray
from .imm import bistatic_loglik, combine, imm_position_update
from .plots import NormalisedPlots
from .predictor import Prediction, imm_arrays
from .state import TrackState


class Updater(Protocol):
    """Updates ``tracks[i]`` with plot ``c`` for each ``(i, c)`` of ``assigned`` in place.

    ``conv`` holds the converted plots, row ``conv_of[c]`` for plot ``c``. Returns the rows updated and
    the rows not updated with the flag saying why.
    """

    def update(
        self,
        tracks: list[TrackState],
        pred: Prediction,
        assigned: dict[int, int],
        plots: NormalisedPlots,
        R_plot: FloatArray,
        conv: ConvertedPlots,
        conv_of: dict[int, int],
    ) -> tuple[list[int], dict[int, str]]: ...


class PclUpdater:
    """The tracker's updater for the configured measurement and motion models (module doc)."""

    def __init__(self, config: TrackerConfig) -> None:
        self.config = config

    def update(
        self,
        tracks: list[TrackState],
        pred: Prediction,
        assigned: dict[int, int],
        plots: NormalisedPlots,
        R_plot: FloatArray,
        conv: ConvertedPlots,
        conv_of: dict[int, int],
    ) -> tuple[list[int], dict[int, str]]:
        trk = self.config
        ukf_rows: list[tuple[int, int]] = []
        bkf_rows: list[tuple[int, int]] = []
        skipped: dict[int, str] = {}
        for i, c in assigned.items():
            if tracks[i].phase == "bkf":
                bkf_rows.append((i, c))
            elif plots.low_rb[c]:
                skipped[i] = "low_rb_hit"
            elif trk.measurement_model == "converted_position" and not bool(conv.valid[conv_of[c]]):
                skipped[i] = "conversion_failed"
            else:
                ukf_rows.append((i, c))
        updated: list[int] = []
        if ukf_rows:
            ii = [i for i, _ in ukf_rows]
            cc = [c for _, c in ukf_rows]
            X = np.stack([tracks[i].x for i in ii])
            P = np.stack([tracks[i].P for i in ii])
            if trk.motion_model == "imm":
                kk = [conv_of[c] for c in cc]
                mu, XM, PM = imm_arrays([tracks[i] for i in ii])
                loglik = None
                if trk.imm_likelihood == "bistatic" and pred.model_images is not None:
                    zm, Sm = pred.model_images
                    loglik = bistatic_loglik(plots.z[cc], zm[ii], Sm[ii], R_plot[cc])
                mu, XM, PM = imm_position_update(mu, XM, PM, conv.y[kk], conv.R[kk], loglik)
                X, P = combine(mu, XM, PM)
                for k, i in enumerate(ii):
                    tracks[i].mu, tracks[i].xm, tracks[i].Pm = mu[k], XM[k], PM[k]
            elif trk.measurement_model == "converted_position":
                kk = [conv_of[c] for c in cc]
                X, P, _ = kf_position_update(X, P, conv.y[kk], conv.R[kk])
            else:
                img = pred.images
                X, P = ukf_bistatic_update(
                    X, P, TransformResult(img.mean[ii], img.cov[ii], img.cross[ii]), plots.z[cc], R_plot[cc]
                )
            for k, i in enumerate(ii):
                tracks[i].x, tracks[i].P = X[k], P[k]
            updated += ii
        if bkf_rows:
            ii = [i for i, _ in bkf_rows]
            cc = [c for _, c in bkf_rows]
            X = np.stack([tracks[i].x for i in ii])
            P = np.stack([tracks[i].P for i in ii])
            X, P = bkf_update(X, P, plots.z[cc], R_plot[cc])
            for k, i in enumerate(ii):
                tracks[i].x, tracks[i].P = X[k], P[k]
            updated += ii
        return updated, skipped
