"""Dead reckoning, Eq. (3)-(4) of digest 002, with a ring buffer for displacement queries (§7.3 S4).

Every DVL or attitude sample makes a knot carrying the horizontal velocity (latest speed rotated by the
latest attitude: with a body-frame 3-D velocity and pitch/roll the full vector is rotated and its
horizontal part kept; the paper's speed x heading is the case pitch = roll = 0 with no transverse
velocity). Between knots the velocity is integrated either with a zero-order hold (``hold``: the
sum of V cos(phi) dt of §4.3) or with the trapezoid of the two knot velocities (``linear``, default [E]:
an instantaneous turn at an unknown instant between two 1 Hz samples then has no lag bias). After the last
knot the velocity is held.

Times are seconds on the data clock (``header.stamp_ns``). Validity: a DVL sample without bottom lock is
not a valid velocity; the last valid one is held for ``dvl_hold_s`` (heading: ``heading_hold_s``), after
which DR is invalid and the position is frozen while ``invalid_s`` (cumulative invalid time) grows.

Besides the position, every knot carries U = integral of the horizontal forward unit vector
(cos(psi) cos(theta), sin(psi) cos(theta)) over the valid DR time (``un_s``, ``ue_s``): the displacement error a
constant DVL speed bias b causes over an interval is b (U_b - U_a), whether the vehicle moves or hovers
(:mod:`services.rd_nav.drift`), and the variance of what the trapezoid misses where the velocity changes
(``interp_var_m2``): a step Δv at an unknown instant within a sample interval Δt leaves (u - 1/2) Δv Δt with u
uniform, variance |Δv|² Δt² / 12 per interval (turns, speed changes, stops and starts).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class DrPoint:
    """Cumulative DR state at one time."""

    t_s: float
    x_m: float  # north
    y_m: float  # east
    path_m: float  # cumulative horizontal path length
    invalid_s: float  # cumulative time with DR invalid
    un_s: float = 0.0  # cumulative time integral of the horizontal forward (heading) unit vector, north, s
    ue_s: float = 0.0  # ... east, s (U of the DR error model: a speed bias b moves DR by b U)
    interp_var_m2: float = 0.0  # cumulative variance of the trapezoid's error at velocity changes, m^2


def body_to_ned_horizontal(
    v_fwd: float, v_stbd: float, v_down: float, heading: float, pitch: float, roll: float
) -> tuple[float, float]:
    """North and east components of a body-frame velocity (ZYX Euler: heading, pitch, roll)."""
    cph, sph = math.cos(roll), math.sin(roll)
    cth, sth = math.cos(pitch), math.sin(pitch)
    cps, sps = math.cos(heading), math.sin(heading)
    vn = cps * cth * v_fwd + (cps * sth * sph - sps * cph) * v_stbd + (cps * sth * cph + sps * sph) * v_down
    ve = sps * cth * v_fwd + (sps * sth * sph + cps * cph) * v_stbd + (sps * sth * cph - cps * sph) * v_down
    return vn, ve


class DeadReckoner:
    """Eq. (4) integrator on the data clock with ``displacement(t_a, t_b)`` queries."""

    def __init__(
        self,
        dvl_hold_s: float = 5.0,
        heading_hold_s: float = 5.0,
        buffer_s: float = 120.0,
        interpolation: Literal["hold", "linear"] = "linear",
    ) -> None:
        self.dvl_hold_s = dvl_hold_s
        self.heading_hold_s = heading_hold_s
        self.buffer_s = buffer_s
        self.linear = interpolation == "linear"
        # knots: time, cumulative state, velocity and how long that velocity stays valid
        self._t: list[float] = []
        self._x: list[float] = []
        self._y: list[float] = []
        self._path: list[float] = []
        self._inv: list[float] = []
        self._un: list[float] = []
        self._ue: list[float] = []
        self._iv: list[float] = []
        self._fn: list[float] = []  # horizontal forward unit vector at the knot
        self._fe: list[float] = []
        self._vn: list[float] = []
        self._ve: list[float] = []
        self._until: list[float] = []
        # held raw inputs
        self._vel_body: tuple[float, float, float] | None = None
        self._t_vel = -math.inf
        self._att: tuple[float, float, float] | None = None  # heading, pitch, roll
        self._t_att = -math.inf

    # ----- inputs ---------------------------------------------------------------------------
    @property
    def last_t(self) -> float | None:
        return self._t[-1] if self._t else None

    def add_velocity(self, t: float, v_fwd: float, v_stbd: float, v_down: float, valid: bool = True) -> None:
        self.advance_to(t)
        if valid:
            self._vel_body = (v_fwd, v_stbd, v_down)
            self._t_vel = t
        self._refresh_last()

    def add_attitude(self, t: float, heading: float, pitch: float = 0.0, roll: float = 0.0) -> None:
        self.advance_to(t)
        self._att = (heading, pitch, roll)
        self._t_att = t
        self._refresh_last()

    def add_heading(self, t: float, heading: float) -> None:
        pitch, roll = (self._att[1], self._att[2]) if self._att is not None else (0.0, 0.0)
        self.add_attitude(t, heading, pitch, roll)

    def advance_to(self, t: float) -> None:
        """Make sure a knot exists at t (t must not precede the last knot)."""
        if not self._t:
            self._append(t, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            self._refresh_last()
            return
        t0 = self._t[-1]
        if t < t0:
            raise ValueError(f"DR sample at {t} s precedes the last one at {t0} s")
        if t == t0:
            return
        self._append(t, *self._segment(len(self._t) - 1, t, None))
        self._refresh_last()
        cut = t - self.buffer_s
        if len(self._t) > 4 and self._t[1] < cut:
            k = bisect.bisect_left(self._t, cut) - 1
            if k > 0:
                for a in (
                    self._t,
                    self._x,
                    self._y,
                    self._path,
                    self._inv,
                    self._un,
                    self._ue,
                    self._iv,
                    self._fn,
                    self._fe,
                    self._vn,
                    self._ve,
                    self._until,
                ):
                    del a[:k]

    # ----- internals --------------------------------------------------------------------------
    def _append(self, t: float, x: float, y: float, path: float, inv: float, un: float, ue: float) -> None:
        self._t.append(t)
        self._x.append(x)
        self._y.append(y)
        self._path.append(path)
        self._inv.append(inv)
        self._un.append(un)
        self._ue.append(ue)
        self._iv.append(self._iv[-1] if self._iv else 0.0)
        self._fn.append(0.0)
        self._fe.append(0.0)
        self._vn.append(0.0)
        self._ve.append(0.0)
        self._until.append(-math.inf)

    def _refresh_last(self) -> None:
        """Velocity at the last knot from the held inputs; its position again (trapezoid uses it)."""
        k = len(self._t) - 1
        if self._vel_body is not None and self._att is not None:
            self._vn[k], self._ve[k] = body_to_ned_horizontal(*self._vel_body, *self._att)
            self._fn[k], self._fe[k] = body_to_ned_horizontal(1.0, 0.0, 0.0, *self._att)
            self._until[k] = min(self._t_vel + self.dvl_hold_s, self._t_att + self.heading_hold_s)
        else:
            self._vn[k], self._ve[k], self._until[k] = 0.0, 0.0, -math.inf
            self._fn[k], self._fe[k] = 0.0, 0.0
        if k > 0 and self.linear:
            seg = self._segment(k - 1, self._t[k], k)
            self._x[k], self._y[k], self._path[k], self._inv[k], self._un[k], self._ue[k] = seg
            dt = self._t[k] - self._t[k - 1]
            both = self._until[k - 1] >= self._t[k] and self._until[k] >= self._t[k]
            dv2 = (self._vn[k] - self._vn[k - 1]) ** 2 + (self._ve[k] - self._ve[k - 1]) ** 2 if both else 0.0
            self._iv[k] = self._iv[k - 1] + dv2 * dt * dt / 12.0

    def _segment(self, a: int, t: float, b: int | None) -> tuple[float, float, float, float, float, float]:
        """State at time t >= t_a integrated from knot a (trapezoid to knot b if given and valid)."""
        ta = self._t[a]
        x, y, path, inv = self._x[a], self._y[a], self._path[a], self._inv[a]
        un, ue = self._un[a], self._ue[a]
        dt = t - ta
        if dt <= 0.0:
            return x, y, path, inv, un, ue
        va = (self._vn[a], self._ve[a])
        fa = (self._fn[a], self._fe[a])
        if b is not None and self._until[a] >= t and self._until[b] >= t:
            vb = (self._vn[b], self._ve[b])
            fb = (self._fn[b], self._fe[b])
            x += 0.5 * (va[0] + vb[0]) * dt
            y += 0.5 * (va[1] + vb[1]) * dt
            path += 0.5 * (math.hypot(*va) + math.hypot(*vb)) * dt
            un += 0.5 * (fa[0] + fb[0]) * dt
            ue += 0.5 * (fa[1] + fb[1]) * dt
            return x, y, path, inv, un, ue
        dt_valid = min(max(self._until[a] - ta, 0.0), dt)
        if dt_valid > 0.0:
            x += va[0] * dt_valid
            y += va[1] * dt_valid
            path += math.hypot(*va) * dt_valid
            un += fa[0] * dt_valid
            ue += fa[1] * dt_valid
        return x, y, path, inv + (dt - dt_valid), un, ue

    # ----- queries --------------------------------------------------------------------------
    def valid_at(self, t: float) -> bool:
        """True if DR had a valid velocity at t (within the buffer or after the last knot)."""
        if not self._t:
            return False
        k = max(bisect.bisect_right(self._t, t) - 1, 0)
        return t <= self._until[k]

    def covers(self, t: float) -> bool:
        return bool(self._t) and t >= self._t[0]

    def at(self, t: float) -> DrPoint:
        """Cumulative DR state at t (linear between knots, held-velocity extrapolation after the last)."""
        if not self._t or t < self._t[0]:
            raise LookupError(f"DR has no data at {t} s")
        if t >= self._t[-1]:
            return DrPoint(t, *self._segment(len(self._t) - 1, t, None), self._iv[-1])
        k = bisect.bisect_right(self._t, t)
        ta, tb = self._t[k - 1], self._t[k]
        f = (t - ta) / (tb - ta) if tb > ta else 0.0

        def lerp(a: list[float]) -> float:
            return a[k - 1] + f * (a[k] - a[k - 1])

        return DrPoint(
            t,
            lerp(self._x),
            lerp(self._y),
            lerp(self._path),
            lerp(self._inv),
            lerp(self._un),
            lerp(self._ue),
            lerp(self._iv),
        )

    def displacement(self, t_a: float, t_b: float) -> tuple[float, float]:
        """Delta X between two data times, Eq. (4), m (north, east)."""
        a, b = self.at(t_a), self.at(t_b)
        return b.x_m - a.x_m, b.y_m - a.y_m
