"""Recorded trajectories as truth: a track file (CSV or Parquet) smoothed and differentiated into a trajectory.

A track file holds one row per recorded fix: a time column plus either **geodetic** positions (latitude,
longitude in degrees on WGS84, height above the ellipsoid in metres) or **local** positions (east, north,
up in metres of the scenario frame), with optional velocity ([east, north, up] m/s) and attitude (heading,
pitch, roll in degrees) columns. GNSS logs, ADS-B tracks and AUV navigation logs all come in this shape.

**Geodesy (pyproj, not flat earth).** Geodetic rows are converted to a local east/north/up frame with PROJ's
``cart`` + ``topocentric`` pipeline (:class:`shared.geodesy.LocalFrame`, which the Foxglove map channels
invert): geodetic -> Earth-centred Cartesian (WGS84) -> the topocentric frame at ``origin`` (default: the first
row). This is an exact rigid transform of the ellipsoid's coordinates; the frame's up axis is the ellipsoid
normal at the origin, so a level flight 100 km away from it shows the Earth's curvature (~785 m of drop), as it
must in a Cartesian frame. :meth:`RecordedTrack.geodetic` converts back (exactly) for consumers that want
latitude, longitude and height, e.g. a map in a projected CRS.

**Smoothing and differentiation (the documented method).** Each ENU axis is fitted, as a function of time,
with a cubic **smoothing spline** (Reinsch; :func:`scipy.interpolate.make_smoothing_spline`) that minimises

    sum_k (p_k - s(t_k))^2 + lambda * integral s''(t)^2 dt,

lambda chosen per axis by **generalised cross-validation** (``smoothing: gcv``, the default) or fixed
(``smoothing_lambda``); ``smoothing: none`` interpolates the rows exactly (a natural cubic spline, for tracks
that are already clean). Position, velocity and acceleration are the spline and its first and second
derivatives, so velocity is the exact derivative of the position that is published (no finite differences).
Recorded velocity columns, when given, replace the spline's first derivative (they are linearly
interpolated). Attitude: recorded columns are interpolated linearly (heading unwrapped); without them
heading = atan2(v_east, v_north) (clockwise from north), pitch = atan2(v_up, v_horizontal) (the flight-path
angle), roll = atan(v_h * omega / g) with the turn rate omega = (v_n a_e - v_e a_n)/v_h^2 (coordinated,
zero-sideslip flight, as :mod:`.trajectory`).

**Time.** The time column is seconds (any numeric origin) or ISO-8601 date-times / Parquet timestamps. The
track's first row is at scenario time ``time_offset_s``; rows must be strictly increasing in time. Outside
the recorded span the track is not extrapolated: :meth:`RecordedTrack.states` raises ``ValueError``, and
:attr:`RecordedTrack.end_s` tells a simulator where to stop.

**Adopting it in a simulator** (the same interface as :class:`.trajectory.Trajectory`: ``states(t_s)``
returns :class:`.trajectory.States`, ``truth_at(stamps_ns)`` a :class:`.base.TruthState`)::

    class MyParams(SimParams):
        track: TrackFileParams | None = None            # 1. a parameter
        ...

    def __init__(self, params, rng, context):
        if params.track is not None:                    # 2. the trajectory from the file
            self.trajectory = RecordedTrack.load(params.track)
        else:
            self.trajectory = Trajectory.from_route(params)
        context.register_platform(params.platform, self.trajectory)

Everything downstream that calls ``states``/``truth_at`` (sensor streams, truth messages, sensor_stats) is
unchanged; the simulator only has to stop at ``trajectory.end_s``.
"""

from __future__ import annotations

import csv
import functools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, model_validator
from scipy.interpolate import CubicSpline, make_smoothing_spline

from shared.geodesy import LocalFrame

from .base import NS_PER_S, SimParams, TruthState
from .trajectory import G_MPS2, TWO_PI, States

F64 = NDArray[np.float64]

GEODETIC_COLUMNS = ("lat_deg", "lon_deg", "alt_m")
LOCAL_COLUMNS = ("east_m", "north_m", "up_m")
VELOCITY_COLUMNS = ("v_east_mps", "v_north_mps", "v_up_mps")
ATTITUDE_COLUMNS = ("heading_deg", "pitch_deg", "roll_deg")
PARQUET_SUFFIXES = (".parquet", ".pq")
#: the repository root: a relative track path that does not exist from the working directory is tried here
REPO_ROOT = Path(__file__).resolve().parents[3]


class GeoPoint(SimParams):
    """A geodetic point on WGS84."""

    lat_deg: float = Field(ge=-90.0, le=90.0, description="latitude, deg")
    lon_deg: float = Field(ge=-180.0, le=180.0, description="longitude, deg")
    alt_m: float = Field(default=0.0, ge=-11_000.0, le=100_000.0, description="height above the ellipsoid, m")


class TrackFileParams(SimParams):
    """Where a recorded trajectory comes from and how it is read (docs/scenarios.md, "Trajectory files")."""

    path: str = Field(min_length=1, max_length=1024, description="CSV or Parquet file (relative: cwd, else repo)")
    time_column: str = Field(default="t_s", min_length=1, description="seconds, or ISO-8601 date-times")
    position: Literal["auto", "geodetic", "local"] = Field(
        default="auto", description="geodetic: lat_deg, lon_deg, alt_m; local: east_m, north_m, up_m; auto: by columns"
    )
    origin: GeoPoint | None = Field(default=None, description="origin of the local ENU frame (default: first row)")
    time_offset_s: float = Field(default=0.0, ge=0.0, le=1e7, description="scenario time of the first row, s")
    smoothing: Literal["gcv", "none"] = Field(
        default="gcv", description="cubic smoothing spline with GCV lambda, or exact interpolation"
    )
    smoothing_lambda: float | None = Field(
        default=None, gt=0.0, description="fixed spline penalty lambda (m^2 s^3 units of the fit), overrides GCV"
    )
    use_recorded_velocity: bool = Field(default=True, description="velocity columns, if present, replace d/dt")
    use_recorded_attitude: bool = Field(default=True, description="attitude columns, if present, are used")

    @model_validator(mode="after")
    def _lambda_needs_smoothing(self) -> TrackFileParams:
        if self.smoothing_lambda is not None and self.smoothing == "none":
            raise ValueError("smoothing_lambda needs smoothing: gcv (it replaces the GCV choice)")
        return self


# --- reading ---------------------------------------------------------------------------------------------------


def resolve_path(path: str | Path) -> Path:
    """An absolute path as is; a relative one from the working directory, else from the repository root."""
    p = Path(path)
    if p.is_absolute() or p.exists():
        return p
    q = REPO_ROOT / p
    return q if q.exists() else p


def read_columns(path: str | Path) -> dict[str, NDArray[np.generic]]:
    """All columns of a CSV (header row, comma-separated, ``#`` comment lines skipped) or Parquet file."""
    p = resolve_path(path)
    if not p.exists():
        raise FileNotFoundError(f"track file {p} does not exist")
    if p.suffix.lower() in PARQUET_SUFFIXES:
        import pyarrow.parquet as pq

        table = pq.read_table(p)
        return {name: table.column(name).to_numpy(zero_copy_only=False) for name in table.column_names}
    with p.open(newline="") as fh:
        rows = [r for r in csv.reader(line for line in fh if line.strip() and not line.lstrip().startswith("#"))]
    if len(rows) < 2:
        raise ValueError(f"{p}: a track needs a header row and at least one data row")
    header = [h.strip() for h in rows[0]]
    body = rows[1:]
    if any(len(r) != len(header) for r in body):
        raise ValueError(f"{p}: every row needs {len(header)} fields")
    out: dict[str, NDArray[np.generic]] = {}
    for k, name in enumerate(header):
        values = [r[k].strip() for r in body]
        try:
            out[name] = np.array([float(v) for v in values], dtype=np.float64)
        except ValueError:
            out[name] = np.array(values, dtype=object)
    return out


def _seconds(col: NDArray[np.generic], where: str) -> F64:
    """A time column as float seconds: numbers as they are; date-times (strings or datetime64) since the epoch."""
    if np.issubdtype(col.dtype, np.number):
        return np.asarray(col, dtype=np.float64)
    try:
        dt = np.asarray(col).astype("datetime64[ns]")
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{where}: the time column is neither seconds nor ISO-8601 date-times ({exc})") from None
    out: F64 = dt.astype(np.int64).astype(np.float64) / NS_PER_S
    return out


def _float_column(cols: dict[str, NDArray[np.generic]], name: str, where: str) -> F64:
    try:
        out: F64 = np.asarray(cols[name], dtype=np.float64)
    except (ValueError, TypeError):
        raise ValueError(f"{where}: column {name!r} is not numeric") from None
    if not np.all(np.isfinite(out)):
        raise ValueError(f"{where}: column {name!r} has a non-finite value")
    return out


# --- the trajectory ----------------------------------------------------------------------------------------------


@dataclass
class _Axis:
    """Position of one axis as a spline, with an optional recorded derivative."""

    spline: CubicSpline | object
    lam: float | None

    def __call__(self, t: F64, nu: int = 0) -> F64:
        out: F64 = np.asarray(self.spline(t, nu), dtype=np.float64)  # type: ignore[operator]
        return out


def _fit_axis(t: F64, y: F64, smoothing: str, lam: float | None) -> _Axis:
    if smoothing == "none" or t.size < 5:
        return _Axis(CubicSpline(t, y, bc_type="natural"), None)
    spl = make_smoothing_spline(t, y, lam=lam)
    return _Axis(spl, lam)


class RecordedTrack:
    """A recorded trajectory, smoothed and differentiated (see the module docstring); times in scenario seconds."""

    def __init__(
        self,
        t_s: F64,
        enu_m: F64,
        frame: LocalFrame | None,
        smoothing: str = "gcv",
        smoothing_lambda: float | None = None,
        velocity_mps: F64 | None = None,
        attitude_rad: F64 | None = None,
        source: str = "",
    ) -> None:
        t = np.asarray(t_s, dtype=np.float64)
        enu = np.asarray(enu_m, dtype=np.float64)
        where = source or "track"
        if t.ndim != 1 or t.size < 2:
            raise ValueError(f"{where}: a track needs at least 2 rows")
        if enu.shape != (t.size, 3):
            raise ValueError(f"{where}: positions must be (n, 3), got {enu.shape}")
        if not np.all(np.diff(t) > 0.0):
            k = int(np.argmin(np.diff(t)))
            raise ValueError(f"{where}: time must be strictly increasing (row {k + 2} is not after row {k + 1})")
        self.source = where
        self.t_rows = t
        self.enu_rows = enu
        self.frame = frame
        self.axes = [_fit_axis(t, enu[:, k], smoothing, smoothing_lambda) for k in range(3)]
        self._vel = velocity_mps
        self._att = None
        if attitude_rad is not None:
            att = np.array(attitude_rad, dtype=np.float64)
            att[:, 0] = np.unwrap(att[:, 0])
            self._att = att

    # --- construction from a file ------------------------------------------------------------------------
    @classmethod
    def load(cls, params: TrackFileParams) -> RecordedTrack:
        """Read, convert (pyproj) and fit a track file."""
        where = str(params.path)
        cols = read_columns(params.path)
        if params.time_column not in cols:
            raise ValueError(f"{where}: no time column {params.time_column!r} (columns: {sorted(cols)})")
        t_raw = _seconds(cols[params.time_column], where)
        t = t_raw - t_raw[0] + params.time_offset_s
        kind = params.position
        if kind == "auto":
            if all(c in cols for c in GEODETIC_COLUMNS[:2]):
                kind = "geodetic"
            elif all(c in cols for c in LOCAL_COLUMNS[:2]):
                kind = "local"
            else:
                raise ValueError(
                    f"{where}: needs columns {GEODETIC_COLUMNS[:2]} (geodetic) or {LOCAL_COLUMNS[:2]} (local)"
                )
        frame: LocalFrame | None = None
        if kind == "geodetic":
            lat = _float_column(cols, "lat_deg", where)
            lon = _float_column(cols, "lon_deg", where)
            alt = _float_column(cols, "alt_m", where) if "alt_m" in cols else np.zeros(lat.size)
            if np.any(np.abs(lat) > 90.0) or np.any(np.abs(lon) > 180.0):
                raise ValueError(f"{where}: latitude or longitude out of range")
            origin = params.origin or GeoPoint(lat_deg=float(lat[0]), lon_deg=float(lon[0]), alt_m=float(alt[0]))
            frame = LocalFrame(origin)
            enu = frame.to_enu(lat, lon, alt)
        else:
            e = _float_column(cols, "east_m", where)
            n = _float_column(cols, "north_m", where)
            u = _float_column(cols, "up_m", where) if "up_m" in cols else np.zeros(e.size)
            enu = np.column_stack([e, n, u])
            if params.origin is not None:
                frame = LocalFrame(params.origin)
        vel = None
        if params.use_recorded_velocity and all(c in cols for c in VELOCITY_COLUMNS):
            vel = np.column_stack([_float_column(cols, c, where) for c in VELOCITY_COLUMNS])
        att = None
        if params.use_recorded_attitude and all(c in cols for c in ATTITUDE_COLUMNS):
            att = np.radians(np.column_stack([_float_column(cols, c, where) for c in ATTITUDE_COLUMNS]))
        return cls(t, enu, frame, params.smoothing, params.smoothing_lambda, vel, att, source=where)

    # --- evaluation --------------------------------------------------------------------------------------------
    @property
    def start_s(self) -> float:
        return float(self.t_rows[0])

    @property
    def has_attitude(self) -> bool:
        """True if the attitude comes from recorded columns (else it is derived from velocity and acceleration)."""
        return self._att is not None

    @property
    def end_s(self) -> float:
        return float(self.t_rows[-1])

    def _check_span(self, t: F64) -> None:
        tol = 1e-9 * max(1.0, abs(self.end_s))
        if t.size and (float(t.min()) < self.start_s - tol or float(t.max()) > self.end_s + tol):
            raise ValueError(
                f"{self.source}: asked for t in [{float(t.min()):.3f}, {float(t.max()):.3f}] s outside the recorded "
                f"span [{self.start_s:.3f}, {self.end_s:.3f}] s (a track is not extrapolated)"
            )

    def states(self, t_s: F64) -> States:
        """Truth at scenario times ``t_s`` (s), [east, north, up] (see the module docstring for the method)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        self._check_span(t)
        t = np.clip(t, self.start_s, self.end_s)
        pos = np.column_stack([ax(t) for ax in self.axes])
        acc = np.column_stack([ax(t, 2) for ax in self.axes])
        if self._vel is not None:
            vel = np.column_stack([np.interp(t, self.t_rows, self._vel[:, k]) for k in range(3)])
        else:
            vel = np.column_stack([ax(t, 1) for ax in self.axes])
        speed = np.hypot(vel[:, 0], vel[:, 1])
        with np.errstate(invalid="ignore", divide="ignore"):
            omega = np.where(speed > 1e-6, (vel[:, 1] * acc[:, 0] - vel[:, 0] * acc[:, 1]) / speed**2, 0.0)
        if self._att is not None:
            heading = np.interp(t, self.t_rows, self._att[:, 0])
            pitch = np.interp(t, self.t_rows, self._att[:, 1])
            roll = np.interp(t, self.t_rows, self._att[:, 2])
        else:
            heading = np.arctan2(vel[:, 0], vel[:, 1])
            pitch = np.arctan2(vel[:, 2], speed)
            roll = np.arctan(speed * omega / G_MPS2)
        return States(
            t_s=t,
            position_m=pos,
            velocity_mps=vel,
            acceleration_mps2=acc,
            heading_rad=np.mod(heading, TWO_PI),
            pitch_rad=pitch,
            roll_rad=roll,
            speed_mps=speed,
            turn_rate_rps=omega,
            climb_rate_mps=vel[:, 2],
        )

    def truth_at(self, stamps_ns: NDArray[np.int64]) -> TruthState:
        s = self.states(np.asarray(stamps_ns, dtype=np.int64) / NS_PER_S)
        return TruthState(s.position_m, s.velocity_mps, s.heading_rad, s.pitch_rad, s.roll_rad)

    def geodetic(self, t_s: F64) -> F64:
        """(n, 3) [lat_deg, lon_deg, alt_m] of the smoothed track (needs a geodetic track or an ``origin``)."""
        if self.frame is None:
            raise ValueError(f"{self.source}: a local track without an origin has no geodetic position")
        return self.frame.to_geodetic(self.states(t_s).position_m)


@functools.lru_cache(maxsize=32)
def load_cached(params: TrackFileParams) -> RecordedTrack:
    """:meth:`RecordedTrack.load`, cached: a parameter validator, the simulator and every Monte-Carlo run of a
    scenario share one fitted track (it is read-only). A missing or unreadable file raises ValueError (in a
    parameter validator: a validation error that names the file)."""
    try:
        return RecordedTrack.load(params)
    except OSError as exc:
        raise ValueError(str(exc)) from None


def write_track_csv(path: str | Path, t_s: F64, columns: dict[str, F64], comment: str = "", precision: int = 9) -> Path:
    """Write a track file (CSV): ``t_s`` then the given columns, one row per time; ``comment`` as ``#`` lines."""
    p = Path(path)
    names = ["t_s", *columns]
    data = np.column_stack(
        [np.asarray(t_s, dtype=np.float64), *(np.asarray(v, dtype=np.float64) for v in columns.values())]
    )
    with p.open("w", newline="") as fh:
        for line in comment.splitlines():
            fh.write(f"# {line}\n")
        w = csv.writer(fh)
        w.writerow(names)
        for row in data:
            w.writerow([f"{v:.{precision}f}" if math.isfinite(v) else "nan" for v in row])
    return p
