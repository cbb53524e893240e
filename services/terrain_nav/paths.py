"""Flight paths over a reference map: waypoints, recorded tracks and the default line across informative terrain.

All positions are in the **map frame** (digest §1.2): x along the map's axis 0 (north by default), z along
axis 1 (east by default); headings are clockwise from +x towards +z, i.e. clockwise from north when x is
north. Geodetic inputs (waypoints, tracks) are converted with pyproj into the map's projected CRS
(:attr:`ReferenceMap.crs`), exactly; a map without a CRS (a synthetic one) takes local east/north metres
as (z, x).

* :func:`waypoint_path`: turn at a fixed rate towards the next waypoint, then straight to it (the player's
  :class:`~services.player.simulators.trajectory.Trajectory`, exact circular arcs);
* :func:`track_path`: a recorded trajectory (:mod:`services.player.simulators.recorded_track`);
* :func:`informative_line`: the default straight flight over a DEM file: the line, among headings every
  15 deg through the roughest parts of the correction zone, that keeps the most cell-scale relief under it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter

from services.player.simulators.recorded_track import RecordedTrack
from services.player.simulators.trajectory import Route, Trajectory

from .geometry import F64, Bool
from .maps import ReferenceMap
from .simulation import PathSamples

#: step of the central difference that turns mapped positions into map-frame velocities, s
VELOCITY_STEP_S = 0.05


def _geodetic_to_map(ref: ReferenceMap, lat_deg: F64, lon_deg: F64) -> tuple[F64, F64]:
    """(x, z) in the map frame of geodetic points (WGS84), through the map's CRS (pyproj)."""
    if not ref.crs:
        raise ValueError("geodetic positions need a map with a CRS (a GeoTIFF or a .npy sidecar with 'crs')")
    from pyproj import CRS, Transformer

    t = Transformer.from_crs(CRS.from_epsg(4326), CRS.from_user_input(ref.crs), always_xy=True)
    east, north = t.transform(np.asarray(lon_deg, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64))
    east, north = np.atleast_1d(east), np.atleast_1d(north)
    return (north, east) if ref.x_axis == "north" else (east, north)


def map_point(
    ref: ReferenceMap, east_north_m: tuple[float, float] | None, lat_lon_deg: tuple[float, float] | None
) -> tuple[float, float]:
    """(x, z) of a point given as local [east, north] map metres or as geodetic (lat, lon)."""
    if lat_lon_deg is not None:
        x, z = _geodetic_to_map(ref, np.array([lat_lon_deg[0]]), np.array([lat_lon_deg[1]]))
        return float(x[0]), float(z[0])
    assert east_north_m is not None
    e, n = east_north_m
    return (n, e) if ref.x_axis == "north" else (e, n)


def ticks(duration_s: float, rate_hz: float) -> F64:
    """Tick times k / rate for every k with k / rate < duration, s (at least one)."""
    n = max(math.floor(duration_s * rate_hz), 1)
    out: F64 = np.arange(n, dtype=np.float64) / rate_hz
    return out


@dataclass(frozen=True)
class MapWaypoint:
    """A waypoint in the map frame: x, z (m), optional altitude (m) and speed on the way to it (m/s)."""

    x: float
    z: float
    h: float | None = None
    speed_mps: float | None = None


def waypoint_path(
    waypoints: list[MapWaypoint],
    speed_mps: float,
    turn_rate_dps: float,
    rate_hz: float,
    duration_cap_s: float | None = None,
    use_altitude: bool = False,
) -> PathSamples:
    """Fly from the first waypoint (heading at the second) through the others; stop at the last one."""
    if len(waypoints) < 2:
        raise ValueError("a waypoint path needs at least 2 waypoints")
    w0, w1 = waypoints[0], waypoints[1]
    heading = math.degrees(math.atan2(w1.z - w0.z, w1.x - w0.x))
    h0 = w0.h if (use_altitude and w0.h is not None) else 0.0
    route = Route.model_validate(
        {
            "start": {"position_m": [w0.z, w0.x, h0], "heading_deg": heading, "speed_mps": speed_mps},
            "waypoints": [
                {
                    "position_m": [w.z, w.x, w.h if (use_altitude and w.h is not None) else h0],
                    **({"speed_mps": w.speed_mps} if w.speed_mps is not None else {}),
                }
                for w in waypoints[1:]
            ],
            "turn_rate_dps": turn_rate_dps,
        }
    )
    traj = Trajectory.from_route(route)
    end = traj.segments[-1].t0_s
    tau = ticks(end if duration_cap_s is None else min(end, duration_cap_s), rate_hz)
    st = traj.states(tau)
    return PathSamples(
        tau=tau,
        x=st.position_m[:, 1],
        z=st.position_m[:, 0],
        vx=st.velocity_mps[:, 1],
        vz=st.velocity_mps[:, 0],
        h=st.position_m[:, 2] if use_altitude else None,
        vh=st.velocity_mps[:, 2] if use_altitude else None,
    )


def track_path(
    track: RecordedTrack,
    ref: ReferenceMap,
    rate_hz: float,
    duration_cap_s: float | None = None,
    use_altitude: bool = False,
) -> PathSamples:
    """A recorded track in the map frame at the flight's ticks, from the track's first row to its last.

    A track with geodetic positions over a map with a CRS goes geodetic -> map CRS (pyproj); its map-frame
    velocity is the central difference (``VELOCITY_STEP_S``) of the mapped smoothed positions, i.e. the
    track's velocity carried through the projection's scale and meridian convergence. Otherwise the track's
    own east/north/up frame is the map frame (x = north, z = east).
    """
    span = track.end_s - track.start_s
    tau = ticks(span if duration_cap_s is None else min(span, duration_cap_s), rate_hz)
    t = track.start_s + tau
    st = track.states(t)
    if track.frame is not None and ref.crs:

        def mapped(ts: F64) -> tuple[F64, F64]:
            g = track.geodetic(np.clip(ts, track.start_s, track.end_s))
            return _geodetic_to_map(ref, g[:, 0], g[:, 1])

        x, z = mapped(t)
        lo, hi = np.maximum(t - VELOCITY_STEP_S, track.start_s), np.minimum(t + VELOCITY_STEP_S, track.end_s)
        (xa, za), (xb, zb) = mapped(lo), mapped(hi)
        vx, vz = (xb - xa) / (hi - lo), (zb - za) / (hi - lo)
        h = track.geodetic(t)[:, 2] if use_altitude else None
    else:
        east, north = st.position_m[:, 0], st.position_m[:, 1]
        ve, vn = st.velocity_mps[:, 0], st.velocity_mps[:, 1]
        x, z, vx, vz = (north, east, vn, ve) if ref.x_axis == "north" else (east, north, ve, vn)
        h = st.position_m[:, 2] if use_altitude else None
    return PathSamples(tau=tau, x=x, z=z, vx=vx, vz=vz, h=h, vh=st.velocity_mps[:, 2] if use_altitude else None)


def local_roughness(ref: ReferenceMap, window_cells: int = 9) -> F64:
    """Local D1 (m^2): the mean over a square window of 0.5[(dh_x)^2 + (dh_z)^2] at each cell (NaN: void)."""
    dem = ref.dem
    d = np.full(dem.shape, np.nan)
    dx = dem[1:, :-1] - dem[:-1, :-1]
    dz = dem[:-1, 1:] - dem[:-1, :-1]
    d[:-1, :-1] = 0.5 * (dx * dx + dz * dz)
    ok = np.isfinite(d)
    num = uniform_filter(np.where(ok, d, 0.0), window_cells, mode="constant")
    den = uniform_filter(ok.astype(np.float64), window_cells, mode="constant")
    out: F64 = np.where(den > 0.25, num / np.maximum(den, 1e-12), np.nan)
    return out


def informative_line(
    ref: ReferenceMap, zone: Bool, length_cells: int, margin_cells: float = 0.0, heading_step_deg: float = 15.0
) -> tuple[tuple[int, int], float]:
    """Start cell and heading (deg) of the default straight flight over a DEM file.

    Lines through the 16 roughest zone cells (local D1, :func:`local_roughness`) in every heading (step
    ``heading_step_deg``) are walked in one-cell steps while they stay in the zone shrunk by
    ``margin_cells`` (room for the INS offset); the score is the sum of the local D1 over the first
    ``length_cells`` cells of the line. The best line's start (the end of its walk backwards from the
    centre, or the point ``length_cells / 2`` before the centre) and heading are returned.
    """
    rough = local_roughness(ref)
    m = math.ceil(margin_cells)
    inner = zone.copy()
    if m > 0:
        from scipy.ndimage import binary_erosion

        inner = binary_erosion(zone, structure=np.ones((2 * m + 1, 2 * m + 1), dtype=bool), border_value=False)
    if not inner.any():
        inner = zone
    score_map = np.where(inner & np.isfinite(rough), rough, -np.inf)
    flat = np.argsort(score_map, axis=None)[::-1][:16]
    centres = [divmod(int(k), zone.shape[1]) for k in flat if np.isfinite(score_map.flat[int(k)])]
    if not centres:
        raise ValueError("the map has no informative zone cell to fly over")
    best: tuple[float, tuple[int, int], float] | None = None
    step = 1.0
    n_half = int(length_cells / step)
    for ci, cj in centres:
        for hd in np.arange(0.0, 360.0, heading_step_deg):
            c, s = math.cos(math.radians(hd)), math.sin(math.radians(hd))
            # walk back from the centre up to half the length, then forward the whole length
            back = 0
            while back < n_half // 2:
                u, v = ci + 0.5 - (back + 1) * step * c, cj + 0.5 - (back + 1) * step * s
                if not _inside(inner, u, v):
                    break
                back += 1
            u0, v0 = ci + 0.5 - back * step * c, cj + 0.5 - back * step * s
            total, k = 0.0, 0
            while k < n_half:
                u, v = u0 + k * step * c, v0 + k * step * s
                if not _inside(inner, u, v):
                    break
                r = rough[int(u), int(v)]
                total += float(r) * step if np.isfinite(r) else 0.0
                k += 1
            if best is None or total > best[0]:
                best = (total, (math.floor(u0), math.floor(v0)), float(hd))
    assert best is not None
    return best[1], best[2]


def _inside(mask: Bool, u: float, v: float) -> bool:
    i, j = math.floor(u), math.floor(v)
    return 0 <= i < mask.shape[0] and 0 <= j < mask.shape[1] and bool(mask[i, j])
