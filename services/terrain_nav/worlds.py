"""Worlds beyond the digest's harness for the issue-16 statistics (coarse, partly flat maps)."""

from __future__ import annotations

import numpy as np

from .maps import ReferenceMap
from .simulation import World
from .terrain import fbm_2d


def coarse_partly_flat_world(seed: int, rng: np.random.Generator) -> World:
    """200 x 101 cells of 2.4 km: mountains (fBm H 0.7, 100 m RMS adjacent change) for z beyond the middle, a
    plain (1 m) before it, a 5-cell transition; the truth is the cell grid itself (bilinear), the DEM
    truth + N(0, 5 m): what a coarse real DEM over a coast or a basin edge looks like to the algorithm."""
    ni, nj, cell = 200, 101, 2400.0
    a = fbm_2d((ni, nj), rng, 0.7, 100.0)
    b = fbm_2d((ni, nj), rng, 0.7, 1.0)
    x = (np.arange(nj) + 0.5) / nj
    w = np.clip((x - 0.5) / 0.05 + 0.5, 0.0, 1.0)[None, :]
    truth = a * w + b * (1.0 - w)
    truth = truth - truth.min() + 100.0
    dem = truth + rng.normal(0.0, 5.0, (ni, nj))
    return World(truth=truth, margin=0, ref_map=ReferenceMap(dem=dem, cell_m=cell), truth_origin_m=(0.0, 0.0),
                 truth_cell_m=cell)  # fmt: skip
