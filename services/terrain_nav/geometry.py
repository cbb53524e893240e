"""Grid geometry: cell indexing (§1.2), hypothesis offsets (§2.1), patch masks and bilinear sampling.

Cell (I, J) covers ``[x0 + I*cell, x0 + (I+1)*cell) x [z0 + J*cell, z0 + (J+1)*cell)``; the map value of a
cell is its mean height and belongs to the cell centre ``(x0 + (I+1/2)*cell, z0 + (J+1/2)*cell)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
Bool = NDArray[np.bool_]


def cell_index(coord_m: float, origin_m: float, cell_m: float) -> int:
    """``floor((coord - origin)/cell)``: the integer cell of a coordinate (§1.2)."""
    return math.floor((coord_m - origin_m) / cell_m)


@dataclass(frozen=True)
class HypothesisGrid:
    """Integer offsets i in -M_x..M_x (longitudinal) and j in -M_z..M_z (transverse), in cells (§2.1)."""

    M_x: int
    M_z: int

    @property
    def shape(self) -> tuple[int, int]:
        return (2 * self.M_x + 1, 2 * self.M_z + 1)

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1]

    def offset_of(self, a: int, b: int) -> tuple[int, int]:
        """Array index (a, b) -> offset (i, j) in cells."""
        return a - self.M_x, b - self.M_z

    def index_of(self, i: int, j: int) -> tuple[int, int]:
        """Offset (i, j) in cells -> array index."""
        return i + self.M_x, j + self.M_z

    def index_arrays(self) -> tuple[F64, F64]:
        """Broadcastable float arrays of the offsets i (shape (n_i, 1)) and j (shape (1, n_j))."""
        i = np.arange(-self.M_x, self.M_x + 1, dtype=np.float64)[:, None]
        j = np.arange(-self.M_z, self.M_z + 1, dtype=np.float64)[None, :]
        return i, j


def window_all(ok: Bool, lo_i: int, hi_i: int, lo_j: int, hi_j: int) -> Bool:
    """``out[I, J]`` = every ``ok[I+a, J+b]`` is True for a in [lo_i, hi_i], b in [lo_j, hi_j] (inside the array).

    Computed with a 2-D summed-area table, so it costs O(size of ok) whatever the window size.
    """
    n_i, n_j = ok.shape
    bad = (~ok).astype(np.int64)
    sat = np.zeros((n_i + 1, n_j + 1), dtype=np.int64)
    sat[1:, 1:] = bad.cumsum(0).cumsum(1)
    out = np.zeros_like(ok)
    I0 = max(0, -lo_i)
    I1 = min(n_i, n_i - hi_i)  # exclusive
    J0 = max(0, -lo_j)
    J1 = min(n_j, n_j - hi_j)
    if I1 <= I0 or J1 <= J0:
        return out
    rows = np.arange(I0, I1)[:, None]
    cols = np.arange(J0, J1)[None, :]
    r0, r1 = rows + lo_i, rows + hi_i + 1
    c0, c1 = cols + lo_j, cols + hi_j + 1
    n_bad = sat[r1, c1] - sat[r0, c1] - sat[r1, c0] + sat[r0, c0]
    out[I0:I1, J0:J1] = n_bad == 0
    return out


def bilinear(grid: F64, u: F64, v: F64) -> F64:
    """Bilinear interpolation of ``grid`` at fractional *cell-centre* indices (u, v) (u = 0 is the centre of row 0).

    Points outside ``[0, n-1]`` are clamped to the edge.
    """
    n_i, n_j = grid.shape
    u = np.clip(u, 0.0, n_i - 1.0)
    v = np.clip(v, 0.0, n_j - 1.0)
    i0 = np.minimum(np.floor(u).astype(np.int64), n_i - 2)
    j0 = np.minimum(np.floor(v).astype(np.int64), n_j - 2)
    fu = u - i0
    fv = v - j0
    g00 = grid[i0, j0]
    g10 = grid[i0 + 1, j0]
    g01 = grid[i0, j0 + 1]
    g11 = grid[i0 + 1, j0 + 1]
    out: F64 = (1.0 - fu) * ((1.0 - fv) * g00 + fv * g01) + fu * ((1.0 - fv) * g10 + fv * g11)
    return out
