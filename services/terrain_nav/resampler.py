"""Block 1: conversion of the raw INS/RA sample rate to the cell-crossing rate (digest §2.9 S1, §2.11).

Synchronised samples ``(t, x_ins, z_ins, h_ins, h_ra, valid)`` are accumulated while the INS-indicated
position stays in one map cell; when the cell (I, J) changes, one :class:`CellMeasurement` is emitted with
the means over the valid samples of the cell. Nothing is formed from invalid samples, for a cell with no
valid sample, or outside the correction zone (an out-of-zone sample discards the open cell). A cell that
takes longer than ``T_cell_max`` to cross (very low ground speed) is emitted anyway [D].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .geometry import Bool


@dataclass(slots=True)
class CellMeasurement:
    """One cell-rate measurement: means over the valid raw samples taken while the INS was in cell (I, J)."""

    t: float  # s, mean time of the samples
    I: int  # noqa: E741 - the digest's cell index
    J: int
    x_mean: float  # m, mean INS-indicated x
    z_mean: float  # m, mean INS-indicated z
    h_ins: float  # m, mean INS (or baro) altitude
    h_ra: float  # m, mean radio-altimeter height
    n: int  # raw samples averaged
    v_ground: float  # m/s, mean INS ground speed
    vh_ins: float | None  # m/s, mean INS vertical speed (None if the INS gives none)
    t_first: float
    t_last: float
    exclude: bool = False  # first residual after a start or gap: not accumulated in F (§2.7)
    reset_before: bool = False  # a gap longer than T_reset preceded it: empty the window first (§2.8)
    s_expected: float = 0.0  # m^2, the e^2 the model expects at the true hypothesis (S_k; 0 if not accumulated)


class CellResampler:
    """Accumulator of the current cell (block 1 of Fig. 1)."""

    def __init__(self, x0_m: float, z0_m: float, cell_m: float, zone: Bool, T_cell_max_s: float = 5.0) -> None:
        self.x0 = x0_m
        self.z0 = z0_m
        self.cell = cell_m
        self.zone = zone
        self.n_i, self.n_j = zone.shape
        self.T_cell_max = T_cell_max_s
        self.I: int | None = None
        self.J: int | None = None
        self._clear_sums()

    def _clear_sums(self) -> None:
        self.n = 0
        self.st = self.sx = self.sz = self.sh = self.sr = self.sv = self.svh = 0.0
        self.n_vh = 0
        self.t_first = self.t_last = 0.0

    def clear(self) -> None:
        """Drop the open cell without emitting it."""
        self.I = None
        self.J = None
        self._clear_sums()

    def in_zone(self, I: int, J: int) -> bool:  # noqa: E741 - cell index
        return 0 <= I < self.n_i and 0 <= J < self.n_j and bool(self.zone[I, J])

    def push(
        self,
        t: float,
        x: float,
        z: float,
        h_ins: float,
        h_ra: float,
        valid: bool = True,
        v_ground: float = 0.0,
        vh: float | None = None,
    ) -> tuple[CellMeasurement | None, bool]:
        """Add one sample; returns (the measurement of the cell just left or None, sample-in-zone flag)."""
        if not valid or not (
            math.isfinite(t) and math.isfinite(x) and math.isfinite(z) and math.isfinite(h_ins) and math.isfinite(h_ra)
        ):
            return None, True  # discarded: never enters the algorithm [P]
        I = math.floor((x - self.x0) / self.cell)  # noqa: E741 - cell index
        J = math.floor((z - self.z0) / self.cell)
        if not self.in_zone(I, J):
            self.clear()  # flush without emitting [P]
            return None, False
        out = None
        if I != self.I or J != self.J or (self.n > 0 and t - self.t_first > self.T_cell_max):
            out = self.flush()
            self.I, self.J = I, J
        if self.n == 0:
            self.t_first = t
        self.n += 1
        self.st += t
        self.sx += x
        self.sz += z
        self.sh += h_ins
        self.sr += h_ra
        self.sv += v_ground
        if vh is not None and math.isfinite(vh):
            self.svh += vh
            self.n_vh += 1
        self.t_last = t
        return out, True

    def flush(self) -> CellMeasurement | None:
        """Emit the open cell (if it holds a valid sample) and clear the accumulator."""
        out = None
        if self.n > 0 and self.I is not None and self.J is not None:
            n = self.n
            out = CellMeasurement(
                t=self.st / n,
                I=self.I,
                J=self.J,
                x_mean=self.sx / n,
                z_mean=self.sz / n,
                h_ins=self.sh / n,
                h_ra=self.sr / n,
                n=n,
                v_ground=self.sv / n,
                vh_ins=self.svh / self.n_vh if self.n_vh else None,
                t_first=self.t_first,
                t_last=self.t_last,
            )
        self.clear()
        return out
