"""Recorded trajectories as truth: the track-file loader (CSV/Parquet), its geodesy and its smoothing."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.player.simulators.recorded_track import (
    GeoPoint,
    LocalFrame,
    RecordedTrack,
    TrackFileParams,
    write_track_csv,
)
from services.player.simulators.trajectory import Route, Trajectory

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "scenarios" / "tracks" / "terrain_nav_s_turn.csv"

# WGS84, for the independent geodesy below
A_M, F_INV = 6378137.0, 298.257223563
E2 = (2.0 - 1.0 / F_INV) / F_INV


def ecef(lat_deg: np.ndarray, lon_deg: np.ndarray, h_m: np.ndarray) -> np.ndarray:
    """Closed-form geodetic -> Earth-centred Cartesian on WGS84 (textbook, independent of PROJ)."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    n = A_M / np.sqrt(1.0 - E2 * np.sin(la) ** 2)
    return np.column_stack(
        [(n + h_m) * np.cos(la) * np.cos(lo), (n + h_m) * np.cos(la) * np.sin(lo), (n * (1.0 - E2) + h_m) * np.sin(la)]
    )


def enu_independent(lat: np.ndarray, lon: np.ndarray, h: np.ndarray, o: GeoPoint) -> np.ndarray:
    """East/north/up at origin ``o``: ECEF difference rotated into the origin's tangent frame."""
    d = ecef(lat, lon, h) - ecef(np.array([o.lat_deg]), np.array([o.lon_deg]), np.array([o.alt_m]))
    la, lo = math.radians(o.lat_deg), math.radians(o.lon_deg)
    r = np.array(
        [
            [-math.sin(lo), math.cos(lo), 0.0],
            [-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)],
            [math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)],
        ]
    )
    out: np.ndarray = d @ r.T
    return out


def s_turn() -> Trajectory:
    """200 m/s, heading 30 deg, a 3 deg/s right turn of 30 s between two straight legs, level at 1000 m."""
    route = Route.model_validate(
        {
            "start": {"position_m": [0.0, 0.0, 1000.0], "heading_deg": 30.0, "speed_mps": 200.0},
            "legs": [{"duration_s": 40.0}, {"duration_s": 30.0, "turn_rate_dps": 3.0}, {"duration_s": 60.0}],
        }
    )
    return Trajectory.from_route(route)


ORIGIN = GeoPoint(lat_deg=45.0, lon_deg=7.0, alt_m=0.0)


def test_geodetic_rows_convert_exactly_to_the_local_frame(tmp_path: Path) -> None:
    """pyproj's topocentric frame equals the closed-form ECEF rotation to 1 mm over 30 km (no flat earth)."""
    frame = LocalFrame(ORIGIN)
    rng = np.random.default_rng(2)
    enu = np.column_stack([rng.uniform(-30e3, 30e3, 50), rng.uniform(-30e3, 30e3, 50), rng.uniform(0, 3e3, 50)])
    geo = frame.to_geodetic(enu)
    np.testing.assert_allclose(enu_independent(geo[:, 0], geo[:, 1], geo[:, 2], ORIGIN), enu, atol=1e-3)
    np.testing.assert_allclose(frame.to_enu(geo[:, 0], geo[:, 1], geo[:, 2]), enu, atol=1e-6)
    # a level flight 30 km east of the origin is below the origin's tangent plane by about d^2/(2R) = 70 m
    level = frame.to_enu(
        np.array([45.0]), np.array([7.0 + 30e3 / (A_M * math.cos(math.radians(45.0)) * math.pi / 180)]), np.array([0.0])
    )
    assert level[0, 2] == pytest.approx(-(30e3**2) / (2 * 6.38e6), rel=0.02)


def test_exact_rows_are_reproduced_and_velocity_is_the_spline_derivative(tmp_path: Path) -> None:
    traj = s_turn()
    t = np.arange(0.0, 130.0, 0.5)
    truth = traj.states(t)
    geo = LocalFrame(ORIGIN).to_geodetic(truth.position_m)
    path = write_track_csv(
        tmp_path / "t.csv", t + 1000.0, {"lat_deg": geo[:, 0], "lon_deg": geo[:, 1], "alt_m": geo[:, 2]}
    )
    track = RecordedTrack.load(TrackFileParams(path=str(path), origin=ORIGIN, smoothing="none", time_offset_s=5.0))
    assert track.start_s == 5.0 and track.end_s == pytest.approx(134.5)
    s = track.states(t + 5.0)
    # the rows themselves (9 decimals of a degree = 0.1 mm)
    np.testing.assert_allclose(s.position_m, truth.position_m, atol=1e-3)
    # between the rows, an interpolating cubic spline of a 200 m/s arc sampled at 2 Hz: the velocity error is
    # bounded by the spline's O(h^3 |p''''|) term; on the straight legs it is exact, in the turn ~0.1 m/s
    tt = np.arange(1.0, 129.0, 0.05)
    s, ref = track.states(tt + 5.0), traj.states(tt)
    straight = (tt < 38.0) | (tt > 72.0)
    assert np.max(np.abs(s.velocity_mps - ref.velocity_mps)[straight]) < 0.2
    assert np.max(np.abs(s.velocity_mps - ref.velocity_mps)) < 1.0  # the kinks at the turn's ends
    with pytest.raises(ValueError, match="outside the recorded span"):
        track.states(np.array([4.0]))


def test_noisy_gnss_track_is_smoothed_to_an_honest_velocity() -> None:
    """2 m GNSS noise at 2 Hz: the GCV smoothing spline's velocity beats the finite difference by far.

    Finite differences of the rows would have an RMS velocity error of sqrt(2)*2 m / 0.5 s = 5.7 m/s per
    axis; the smoothed track must stay under 1 m/s RMS per horizontal axis (measured ~0.5 m/s) and its
    position under the 2 m noise (measured ~0.8 m), and the turn rate in the turn within 0.5 deg/s of 3.
    """
    track = RecordedTrack.load(TrackFileParams(path=str(EXAMPLE), origin=ORIGIN))
    traj = s_turn()
    tt = np.arange(2.0, 128.0, 0.1)
    s, ref = track.states(tt), traj.states(tt)
    # the example file is in its own ENU frame at its first row, which is the trajectory's origin
    pos_rms = np.sqrt(np.mean((s.position_m - ref.position_m) ** 2, axis=0))
    vel_rms = np.sqrt(np.mean((s.velocity_mps - ref.velocity_mps) ** 2, axis=0))
    assert np.all(pos_rms[:2] < 2.0), pos_rms
    assert np.all(vel_rms[:2] < 1.0), vel_rms
    turn = (tt > 48.0) & (tt < 62.0)
    assert abs(float(np.degrees(np.median(s.turn_rate_rps[turn]))) - 3.0) < 0.5
    # coordinated-flight roll from the smoothed motion: atan(200 * 3 deg/s / g) = 46.9 deg
    assert float(np.degrees(np.median(s.roll_rad[turn]))) == pytest.approx(46.9, abs=4.0)


def test_parquet_and_iso_times_read_as_the_csv(tmp_path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    t = np.arange(0.0, 20.0, 1.0)
    east, north = 100.0 * t, 50.0 * t
    csv_path = write_track_csv(
        tmp_path / "l.csv", t, {"east_m": east, "north_m": north, "up_m": np.full(t.size, 300.0)}
    )
    stamps = np.datetime64("2024-05-01T12:00:00", "ns") + (t * 1e9).astype("timedelta64[ns]")
    pq.write_table(
        pa.table({"time": pa.array(stamps), "east_m": east, "north_m": north, "up_m": np.full(t.size, 300.0)}),
        tmp_path / "l.parquet",
    )
    a = RecordedTrack.load(TrackFileParams(path=str(csv_path), smoothing="none"))
    b = RecordedTrack.load(TrackFileParams(path=str(tmp_path / "l.parquet"), time_column="time", smoothing="none"))
    tt = np.linspace(0.0, 19.0, 77)
    np.testing.assert_allclose(a.states(tt).position_m, b.states(tt).position_m, atol=1e-9)
    np.testing.assert_allclose(b.states(tt).velocity_mps, np.tile([100.0, 50.0, 0.0], (tt.size, 1)), atol=1e-9)
    iso = tmp_path / "iso.csv"
    iso.write_text(
        "t_s,east_m,north_m\n2024-05-01T12:00:00,0,0\n2024-05-01T12:00:10,1000,0\n2024-05-01T12:00:20,2000,0\n"
    )
    c = RecordedTrack.load(TrackFileParams(path=str(iso), smoothing="none"))
    assert c.end_s == 20.0 and c.states(np.array([5.0])).velocity_mps[0, 0] == pytest.approx(100.0)


def test_bad_track_files_are_refused_with_the_reason(tmp_path: Path) -> None:
    p = tmp_path / "bad.csv"
    p.write_text("t_s,east_m,north_m\n0,0,0\n2,1,1\n1,2,2\n")
    with pytest.raises(ValueError, match="strictly increasing"):
        RecordedTrack.load(TrackFileParams(path=str(p)))
    p.write_text("t_s,x,y\n0,0,0\n1,1,1\n")
    with pytest.raises(ValueError, match="needs columns"):
        RecordedTrack.load(TrackFileParams(path=str(p)))
    p.write_text("t_s,lat_deg,lon_deg\n0,95,0\n1,95,0\n")
    with pytest.raises(ValueError, match="out of range"):
        RecordedTrack.load(TrackFileParams(path=str(p)))
    with pytest.raises(FileNotFoundError):
        RecordedTrack.load(TrackFileParams(path=str(tmp_path / "none.csv")))


@settings(max_examples=25, deadline=None)
@given(
    heading=st.floats(0.0, 359.0),
    speed=st.floats(1.0, 300.0),
    climb=st.floats(-20.0, 20.0),
    dt=st.floats(0.1, 5.0),
)
def test_a_straight_track_gives_its_own_velocity_and_heading(
    heading: float, speed: float, climb: float, dt: float
) -> None:
    """Property: for any straight, constant-velocity local track, both fits return the exact velocity and the
    heading atan2(v_e, v_n); the smoothing spline of exactly linear data is that line (GCV or not)."""
    t = np.arange(12) * dt
    ve, vn = speed * math.sin(math.radians(heading)), speed * math.cos(math.radians(heading))
    enu = np.column_stack([ve * t, vn * t, 500.0 + climb * t])
    for smoothing in ("none", "gcv"):
        track = RecordedTrack(t, enu, None, smoothing)
        s = track.states(np.linspace(t[0], t[-1], 9))
        np.testing.assert_allclose(s.velocity_mps, np.tile([ve, vn, climb], (9, 1)), atol=1e-6 * max(speed, 1.0))
        wrapped = (np.degrees(s.heading_rad) - heading + 180.0) % 360.0 - 180.0
        assert np.all(np.abs(wrapped) < 1e-6)
        assert np.allclose(s.roll_rad, 0.0, atol=1e-6)
