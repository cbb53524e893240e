"""Deriving N_min and N_max from the reference map (digest §2.12, optional; the defaults are fixed 24/64).

* **N_min** by self-matching Monte Carlo on the map: K random straight profiles along +x inside the zone
  (random start cell and sub-cell offset) are "measured" from the map itself (cell-averaged bilinear reads
  + white noise sigma_n + a random altitude bias) and run through the cell-rate KF bank with the INS on the
  true track (so the right hypothesis is (0, 0)). N_min is the smallest N in 8, 12, 16, ... whose global
  argmin lies within 1 cell of the truth in at least ``derive_success`` of the profiles, floored at 8.
  The K profiles run as one vectorised bank; the success at each N uses the first N measurements of the
  same profiles (common random numbers across N).
* **N_max** = min(4 N_min, floor(V_nom / (4 sigma_Vh))), which keeps the smear from a horizontal velocity
  error within a quarter cell; a configuration with N_max < N_min + N_s is infeasible.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from .config import TerrainNavConfig
from .filter import KalmanBank
from .geometry import bilinear
from .maps import ReferenceMap
from .models import measurement_variance


def n_max_from(N_min: int, cfg: TerrainNavConfig) -> int:
    """N_max = min(4 N_min, floor(V_nom/(4 sigma_Vh)))."""
    return int(min(4 * N_min, math.floor(cfg.nominal_speed_mps / (4.0 * cfg.sigma_Vh_expected_mps))))


def self_matching_success(
    ref: ReferenceMap, cfg: TerrainNavConfig, n_values: list[int], rng: np.random.Generator, K: int
) -> dict[int, float]:
    """Share of K self-matched profiles whose argmin is within 1 cell of the truth after N measurements."""
    Mx, Mz = cfg.M_x, cfg.M_z
    zone = ref.zone_mask(Mx, Mz)
    n_cap = max(n_values)
    # starts (I, J) with cells I..I+n_cap of column J all in the zone (n_cap residuals + the excluded first)
    runs = sliding_window_view(zone, (n_cap + 1, 1)).all(axis=(2, 3))
    starts = np.argwhere(runs)
    if starts.size == 0:
        raise ValueError(f"no straight profile of {n_cap} cells fits the zone of this map")
    pick = starts[rng.integers(0, len(starts), K)]
    I0, J0 = pick[:, 0], pick[:, 1]
    v0 = rng.uniform(0.0, 1.0, K)  # transverse sub-cell offset (the along-track one averages out per cell)
    n_nom = max(round(cfg.base_samples_per_cell(ref.cell_m)), 1)
    sigma_n = math.sqrt(cfg.sigma_v_m**2 / n_nom + cfg.sigma_map_m**2)
    bias = rng.normal(0.0, 50.0, K)
    patches = sliding_window_view(ref.dem, (2 * Mx + 1, 2 * Mz + 1))
    bank = KalmanBank((K, 2 * Mx + 1, 2 * Mz + 1), cfg.P0, cfg.phi31, cfg.q_a, cfg.q_h)
    F = np.zeros((K, 2 * Mx + 1, 2 * Mz + 1))
    R = measurement_variance(n_nom, cfg.sigma_v_m, cfg.sigma_map_m, cfg.c_q, ref.D1_m2)
    sub = (np.arange(8) + 0.5) / 8.0  # points along the cell for the cell average
    dt = ref.cell_m / cfg.nominal_speed_mps
    out: dict[int, float] = {}
    for k in range(n_cap + 1):
        # true path crosses cell I0+k at transverse fraction v0; the map value is read bilinearly
        uu = (I0 + k)[:, None] + sub[None, :] - 0.5
        vv = np.broadcast_to((J0 + v0)[:, None] - 0.5, uu.shape)
        h_meas = bilinear(ref.dem, uu, vv).mean(axis=1) + rng.normal(0.0, sigma_n, K)
        # y = H + h_ra - h_ins with h_ins - h_ra = terrain + bias: c = -(h_meas + bias) per profile
        c = -(h_meas + bias)
        patch = patches[I0 + k - Mx, J0 - Mz]  # (K, n_i, n_j): hypothesis patch around the INS cell
        bank.predict(k * dt)
        nu = np.subtract(patch + c[:, None, None], bank.x[2])
        if k > 0:
            F += nu * nu
        bank.update(nu, R)
        n = k  # residuals accumulated so far (the first is excluded)
        if n in n_values:
            flat = F.reshape(K, -1).argmin(axis=1)
            a, b = np.divmod(flat, F.shape[2])
            ok = (np.abs(a - Mx) <= 1) & (np.abs(b - Mz) <= 1)
            out[n] = float(ok.mean())
    return out


def derive_n_limits(ref: ReferenceMap, cfg: TerrainNavConfig, n_cap: int = 64) -> tuple[int, int]:
    """(N_min, N_max) from the map by the §2.12 recipe; raises ValueError if infeasible."""
    rng = np.random.default_rng(cfg.derive_seed)
    n_values = list(range(8, n_cap + 1, 4))
    success = self_matching_success(ref, cfg, n_values, rng, cfg.derive_profiles)
    good = [n for n in n_values if success.get(n, 0.0) >= cfg.derive_success]
    if not good:
        raise ValueError(f"the map is not informative enough: success {success} never reaches {cfg.derive_success}")
    N_min = max(8, min(good))
    N_max = n_max_from(N_min, cfg)
    if N_max < N_min + cfg.N_s:
        raise ValueError(f"infeasible window: N_max={N_max} < N_min + N_s = {N_min + cfg.N_s}")
    return N_min, N_max
