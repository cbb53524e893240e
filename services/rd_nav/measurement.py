"""The measurement-noise covariance R of one cycle (digest §4.2, §4.6), evaluated at a horizontal position.

    R = c^2 [sigma_t^2 (I + 1 1^T) + sigma_f^2 I] + (sigma_c / c)^2 s s^T + J_A Sigma_A J_A^T + R_mc

with s_j the total path differences, J_A Sigma_A J_A^T the node-coordinate term (sigma_node, or the packets'
own position sigmas), and R_mc the motion-compensation term of delta_j:

* with the DR error states in the filter (``process_model: dr_errors``) each particle compensates with its own
  errors, so only the white DR noise of the intra-cycle displacements remains, shared by followers j, k over the
  shorter of the two: R_mc[j, k] = u_j^T (C_white(Delta t_i) + iv_i / 2 I) u_k, i = argmin(Delta t_j, Delta t_k);
* otherwise (``process_model: paper``) a DR velocity error sigma_v: R_mc[j, k] = sigma_v^2 Delta t_j Delta t_k
  u_j . u_k (geometry.motion_comp_cov).
"""

from __future__ import annotations

import numpy as np

from .config import RdNavConfig
from .cycle import CycleData
from .drift import DriftModel
from .geometry import F64, follower_units, measurement_cov, motion_comp_cov, node_cov_term


class MeasurementModel:
    """R of §4.2 for a cycle (config and DR error model fixed at construction)."""

    def __init__(self, cfg: RdNavConfig, drift: DriftModel | None) -> None:
        self.cfg = cfg
        self.drift = drift

    def cov(self, cd: CycleData, at: F64) -> F64:
        """R (M, M), m^2, for the cycle ``cd`` at the horizontal position ``at`` (north, east, m)."""
        cfg = self.cfg
        M = cd.d.size
        sig = np.full(M + 1, cfg.sigma_node_m)
        if cfg.use_packet_pos_sigma:
            sig = np.maximum(sig, cd.pos_sigma)
        node = None
        if np.any(sig > 0.0):
            zj = np.full(M, cd.depth)
            node = node_cov_term(at, cd.depth, zj, cd.delta, cd.leader, cd.followers, float(sig[0]), sig[1:])
        if cfg.motion_compensation and self.drift is not None:
            zj = np.full(M, cd.depth)
            u = follower_units(at, zj, cd.delta, cd.followers)
            mc: F64 = np.zeros((M, M))
            for j in range(M):
                for k in range(j, M):
                    i = j if cd.dt[j] <= cd.dt[k] else k
                    C = self.drift.white_cov(float(cd.dt[i]), cd.delta[i], cd.G[i][:, 0])
                    C = C + 0.5 * float(cd.iv[i]) * np.eye(2)
                    mc[j, k] = mc[k, j] = float(u[j] @ C @ u[k])
            node = mc if node is None else node + mc
        elif cfg.motion_compensation and cfg.sigma_dr_velocity_mps > 0.0:
            zj = np.full(M, cd.depth)
            mc = motion_comp_cov(at, zj, cd.delta, cd.followers, cd.dt, cfg.sigma_dr_velocity_mps)
            node = mc if node is None else node + mc
        sigma_c = cd.sigma_c if cfg.include_sound_speed_in_r else 0.0
        return measurement_cov(cd.s, cd.c, cfg.sigma_t_s, cfg.sigma_f_s, sigma_c, node)
