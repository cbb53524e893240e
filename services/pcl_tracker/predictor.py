"""The predictor: each live track extrapolated to the scan time and mapped to bistatic coordinates.

Digest 003 §2.6 steps 1–2, for a track last updated at t_last and a scan at t(k), tau_k = t(k) - t_last:

* phase "ukf" (Cartesian state x_a = [x, y, z, v_x, v_y, v_z], §1.6), CV model:

      x_a(k|k-1) = F x_a(k-1|k-1),   P_a(k|k-1) = F P_a(k-1|k-1) F^T + Q_a,
      F = [[I_3, tau I_3], [0, I_3]],  Q_a = q [[tau^4/4 I_3, tau^3/2 I_3], [tau^3/2 I_3, tau^2 I_3]]

  (:func:`shared.filters.kalman.predict` with :func:`.models.cv_transition`, :func:`.models.cv_process_noise`),
  then the inverse UT (n = 6, 12 points) through h_b: z_b(k|k-1) = E[h_b(x_a)], R_b(k|k-1) its covariance
  (and the cross-covariance P_xz when the 4-D bistatic update needs it);
* phase "ukf" with the IMM ([E], :mod:`.imm`): mixing, the model-matched CV predictions with q_j, and the
  moment-matched mixture; every model's image through h_b is kept for the gate (the union of the models'
  gates) and the track's own z_b(k|k-1), R_b(k|k-1) is the mixture of those images;
* phase "bkf" (bistatic state x_b = [r_b, v_b, alpha, alpha_dot, eps, eps_dot], the BKF of §2.5):
  x_b(k|k-1) = F_b x_b, P_b(k|k-1) = F_b P_b F_b^T + Q_b (alpha wrapped), z_b(k|k-1) = H_b x_b(k|k-1),
  R_b(k|k-1) = H_b P_b(k|k-1) H_b^T (linear).

Tracks keep x(k|k-1), P(k|k-1) (a miss leaves them as the estimate, §2.6 step 7).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from shared.filters.covariance import CholeskyStats
from shared.filters.unscented import TransformResult

from .config import TrackerConfig
from .filter import bistatic_image, bkf_measurement, bkf_predict, predict
from .geometry import FloatArray
from .imm import combine, combine_measurements, imm_predict
from .state import TrackState


@dataclass
class Prediction:
    """The predicted bistatic measurements of a list of tracks, row i for track i."""

    #: z_b(k|k-1) (n, 4), R_b(k|k-1) (n, 4, 4) and, for the 4-D bistatic update, P_xz (n, 6, 4)
    images: TransformResult
    #: IMM: every model's z_b (n, r, 4) and R_b (n, r, 4, 4); None without the IMM
    model_images: tuple[FloatArray, FloatArray] | None = None


class Predictor(Protocol):
    """Predicts tracks in place to the scan time (tau in s per track) and returns their bistatic images."""

    def predict(
        self, tracks: list[TrackState], tau: FloatArray, tx: FloatArray, chol: CholeskyStats | None = None
    ) -> Prediction: ...


class BistaticPredictor:
    """The tracker's predictor: CV (or the IMM) for Cartesian tracks, the linear BKF for bistatic ones (module doc)."""

    def __init__(self, config: TrackerConfig) -> None:
        self.config = config

    def predict(
        self, tracks: list[TrackState], tau: FloatArray, tx: FloatArray, chol: CholeskyStats | None = None
    ) -> Prediction:
        trk = self.config
        n = len(tracks)
        model_images: tuple[FloatArray, FloatArray] | None = None
        cross = trk.measurement_model == "bistatic_ukf4"  # only that update uses the cross-covariance
        out = TransformResult(np.zeros((n, 4)), np.zeros((n, 4, 4)), np.zeros((n, 6, 4) if cross else (n, 0, 0)))
        phases = [tr.phase for tr in tracks]
        for phase in ("ukf", "bkf"):
            idx = [i for i in range(n) if phases[i] == phase]
            if not idx:
                continue
            X = np.stack([tracks[i].x for i in idx])
            P = np.stack([tracks[i].P for i in idx])
            if phase == "ukf" and trk.motion_model == "imm":
                mu, XM, PM = imm_arrays([tracks[i] for i in idx])
                c, XM, PM = imm_predict(mu, XM, PM, tau[idx], trk.imm_models)
                X, P = combine(c, XM, PM)
                for k, i in enumerate(idx):
                    tracks[i].mu, tracks[i].xm, tracks[i].Pm = c[k], XM[k], PM[k]  # a miss keeps these
                r = XM.shape[1]
                img = bistatic_image(XM.reshape(-1, 6), PM.reshape(-1, 6, 6), tx, trk.transform, chol, False)
                zm, Sm = img.mean.reshape(len(idx), r, 4), img.cov.reshape(len(idx), r, 4, 4)
                model_images = (zm, Sm)
                res = TransformResult(*combine_measurements(c, zm, Sm), np.zeros((len(idx), 0, 0)))
            elif phase == "ukf":
                X, P = predict(X, P, tau[idx], trk.q_accel_var_m2s4)
                res = bistatic_image(X, P, tx, trk.transform, chol, with_cross=cross)
            else:
                X, P = bkf_predict(X, P, tau[idx], trk.bkf_q_r_m2s4, trk.bkf_q_ang_rad2s4)
                res = bkf_measurement(X, P)
            for k, i in enumerate(idx):
                tr = tracks[i]
                tr.x = X[k]
                tr.P = P[k]
            out.mean[idx], out.cov[idx] = res.mean, res.cov
            if cross:
                out.cross[idx] = res.cross
        return Prediction(out, model_images)


def imm_arrays(trs: list[TrackState]) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Stacked (mu, xm, Pm) of IMM tracks."""
    mu, xm, Pm = [], [], []
    for t in trs:
        assert t.mu is not None and t.xm is not None and t.Pm is not None
        mu.append(t.mu)
        xm.append(t.xm)
        Pm.append(t.Pm)
    return np.stack(mu), np.stack(xm), np.stack(Pm)
