"""Write the shipped example tracks of the simulators that take ``track:`` (deterministic, no download)::

    python -m tools.example_tracks            # rewrites scenarios/tracks/{auv_lbl_stop,auv_rd_stop,adsb_turn}.csv

* ``scenarios/tracks/auv_lbl_stop.csv`` (``lbl_nav``): an AUV navigation log in the S2 beacon field (B1 at
  (0, 0), B2 at (0, 1500) m east/north): 1 Hz, 300 s at 30 m depth; 2 m/s on heading 325 deg, through the
  S2 launch point (450, 606.97) at t = 60 s; slows to a stop at t = 110 s (10 s linear ramp), hovers 30 s,
  speeds up again (10 s), turns left 70 deg in 30 s (t = 150-180 s) and runs on at heading 255 deg. Local
  east/north/up columns plus the logged heading, pitch and roll (0); exact (a post-processed log: play it with
  ``smoothing: none``).
* ``scenarios/tracks/auv_rd_stop.csv`` (``rd_group`` mover): an AUV inside the REF triangle of the RD-LBL
  field (digest 002: nodes n2 (0, 0), n3 (0, 3000), n1 at the apex, NED north/east; the scenario frame is
  east = NED east, north = NED north): 0.5 Hz, 600 s at 80 m depth; 1.5 m/s north from (east 1500, north
  450) for 200 s, a stop of 60 s (10 s ramps), a right turn of 90 deg in 60 s and east for the rest. Same
  columns as above, exact.
* ``scenarios/tracks/adsb_turn.csv`` (``attitude`` and ``pcl_tracker``): an ADS-B-like aircraft track, 1 Hz,
  300 s, ISO-8601 UTC times, WGS84 latitude/longitude and height: 200 m/s level at 5000 m over the local
  frame at 45.0 N 7.0 E (where the scenarios put the radar or the PCL receiver), heading 110 deg for 100 s,
  a coordinated right turn to heading 200 deg (4 s roll-in at 0.5 then 1 deg/s, 56 s at 1.5 deg/s = 28 deg of bank,
  4 s roll-out), then straight for 136 s.
  Position noise as ADS-B reports it: 3 m (1 sigma) white per horizontal axis and the height quantised to
  25 ft (the barometric altitude's resolution: 2.2 m RMS). No velocity or attitude columns: the player's
  smoothing spline (GCV) differentiates it and the attitude follows from the velocity and acceleration.
"""

from __future__ import annotations

import argparse
import csv
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from services.player.simulators.recorded_track import REPO_ROOT, GeoPoint, LocalFrame, write_track_csv
from services.player.simulators.trajectory import Route, Trajectory

F64 = NDArray[np.float64]
TRACKS = Path("scenarios/tracks")
LBL_TRACK = TRACKS / "auv_lbl_stop.csv"
RD_TRACK = TRACKS / "auv_rd_stop.csv"
ADSB_TRACK = TRACKS / "adsb_turn.csv"
#: the local frame of the aircraft track (the radar / PCL receiver of the scenarios that fly it)
ADSB_ORIGIN = GeoPoint(lat_deg=45.0, lon_deg=7.0, alt_m=0.0)
ADSB_START = datetime(2026, 3, 14, 9, 0, 0, tzinfo=UTC)
FT_M = 0.3048
#: the turn rates of the aircraft's roll-in (2 s each; the roll-out is the reverse): 4 s to 28 deg of bank
ROLL_IN_DPS = (0.5, 1.0)
#: integration step of the AUV kinematics, s
FINE_S = 0.01


def _profile(knots: list[tuple[float, float]], t: F64) -> F64:
    kt, kv = zip(*knots, strict=True)
    out: F64 = np.interp(t, kt, kv)
    return out


def auv_track(
    start_en: tuple[float, float],
    speed_knots: list[tuple[float, float]],
    heading_knots: list[tuple[float, float]],
    duration_s: float,
    period_s: float,
) -> tuple[F64, F64, F64, F64]:
    """(t, east, north, heading deg) of an AUV with piecewise-linear speed and heading profiles, integrated on a
    0.01 s grid (trapezoid), sampled every ``period_s``."""
    t = np.arange(0.0, duration_s + FINE_S / 2, FINE_S)
    v = _profile(speed_knots, t)
    h = np.radians(_profile(heading_knots, t))
    ve, vn = v * np.sin(h), v * np.cos(h)
    east = start_en[0] + np.concatenate([[0.0], np.cumsum(0.5 * (ve[1:] + ve[:-1]) * FINE_S)])
    north = start_en[1] + np.concatenate([[0.0], np.cumsum(0.5 * (vn[1:] + vn[:-1]) * FINE_S)])
    step = round(period_s / FINE_S)
    sl = slice(None, None, step)
    return t[sl], east[sl], north[sl], np.mod(np.degrees(h[sl]), 360.0)


def write_auv(path: Path, t: F64, east: F64, north: F64, heading: F64, depth_m: float, comment: str) -> Path:
    zeros = np.zeros(t.size)
    cols = {"east_m": east, "north_m": north, "up_m": np.full(t.size, -depth_m)}
    cols |= {"heading_deg": heading, "pitch_deg": zeros, "roll_deg": zeros}
    return write_track_csv(path, t, cols, comment)


def lbl_track() -> tuple[F64, F64, F64, F64]:
    """The ``lbl_nav`` AUV, shifted so that it passes the S2 launch point at t = 60 s."""
    speed = [(0.0, 2.0), (100.0, 2.0), (110.0, 0.0), (140.0, 0.0), (150.0, 2.0), (300.0, 2.0)]
    heading = [(0.0, 325.0), (150.0, 325.0), (180.0, 255.0), (300.0, 255.0)]
    t, e, n, h = auv_track((0.0, 0.0), speed, heading, 300.0, 1.0)
    k = int(np.argmin(np.abs(t - 60.0)))
    return t, e - e[k] + 450.0, n - n[k] + 606.97, h


def rd_track() -> tuple[F64, F64, F64, F64]:
    speed = [(0.0, 1.5), (200.0, 1.5), (210.0, 0.0), (270.0, 0.0), (280.0, 1.5), (600.0, 1.5)]
    heading = [(0.0, 0.0), (280.0, 0.0), (340.0, 90.0), (600.0, 90.0)]
    return auv_track((1500.0, 450.0), speed, heading, 600.0, 2.0)


def adsb_route() -> Route:
    return Route.model_validate(
        {
            "start": {"position_m": [-30000.0, 25000.0, 5000.0], "heading_deg": 110.0, "speed_mps": 200.0},
            "legs": [
                {"duration_s": 100.0},
                *({"duration_s": 2.0, "turn_rate_dps": r} for r in ROLL_IN_DPS),
                {"duration_s": 56.0, "turn_rate_dps": 1.5},
                *({"duration_s": 2.0, "turn_rate_dps": r} for r in ROLL_IN_DPS[::-1]),
                {"duration_s": 136.0},
            ],
        }
    )


def write_adsb(path: Path, seed: int = 16) -> Path:
    t = np.arange(0.0, 300.0 + 1e-9, 1.0)
    pos = Trajectory.from_route(adsb_route()).states(t).position_m
    rng = np.random.default_rng(seed)
    pos[:, :2] += rng.normal(0.0, 3.0, (t.size, 2))
    pos[:, 2] = np.round(pos[:, 2] / (25.0 * FT_M)) * (25.0 * FT_M)
    geo = LocalFrame(ADSB_ORIGIN).to_geodetic(pos)
    with path.open("w", newline="") as fh:
        fh.write(
            "# fixstream example ADS-B-like track (tools/example_tracks.py): 200 m/s level at 5000 m, heading 110 deg\n"
            "# for 100 s, right turn 1.5 deg/s for 60 s, heading 200 deg for 140 s; 1 Hz, 3 m horizontal noise,\n"
            "# height quantised to 25 ft; WGS84; local frame origin (radar / receiver) 45.0 N 7.0 E 0 m\n"
        )
        w = csv.writer(fh)
        w.writerow(["time", "lat_deg", "lon_deg", "alt_m"])
        for ti, (lat, lon, h) in zip(t.tolist(), geo.tolist(), strict=True):
            stamp = (ADSB_START + timedelta(seconds=ti)).strftime("%Y-%m-%dT%H:%M:%S.%f")
            w.writerow([stamp, f"{lat:.9f}", f"{lon:.9f}", f"{h:.3f}"])
    return path


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", type=Path, default=REPO_ROOT)
    args = ap.parse_args(argv)
    (args.root / TRACKS).mkdir(parents=True, exist_ok=True)
    t, e, n, h = lbl_track()
    print(
        write_auv(
            args.root / LBL_TRACK,
            t,
            e,
            n,
            h,
            30.0,
            "fixstream example AUV log (tools/example_tracks.py): S2 beacon field, 2 m/s heading 325 deg through the\n"
            "launch point (450, 606.97) at t = 60 s, stop 110-140 s, left turn to 255 deg at 150-180 s; 30 m depth",
        )
    )
    t, e, n, h = rd_track()
    print(
        write_auv(
            args.root / RD_TRACK,
            t,
            e,
            n,
            h,
            80.0,
            "fixstream example AUV log (tools/example_tracks.py): inside the RD-LBL REF triangle, 1.5 m/s north,\n"
            "stop 210-270 s, right turn to east at 280-340 s; 80 m depth",
        )
    )
    print(write_adsb(args.root / ADSB_TRACK))


if __name__ == "__main__":
    main()
