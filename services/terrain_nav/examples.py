"""Write the shipped example inputs: ``python -m services.terrain_nav.examples`` (deterministic, no download).

* ``scenarios/maps/terrain_nav_geo_fbm.tif``: a DEM in a **geographic** CRS (EPSG:4326, 0.001 deg pixels,
  i.e. 111 m x 79 m at 45 N), 2-D fBm (H = 0.6) scaled to an RMS adjacent-pixel change of 10 m, heights as
  int16 metres (deflate-compressed). A stand-in for an SRTM tile that exercises the reprojection path.
* ``scenarios/tracks/terrain_nav_s_turn.csv``: a recorded-style GNSS track over that map: 200 m/s at
  heading 30 deg, a 3 deg/s right turn of 30 s, then straight (130 s in all), level at 1000 m, sampled at
  2 Hz with 2 m white noise per axis on east/north/up, written as latitude/longitude/height on WGS84 (the
  local frame's origin, the flight's start, is 45.0 N, 7.0 E, 0 m).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from services.player.simulators.recorded_track import GeoPoint, LocalFrame, write_track_csv
from services.player.simulators.trajectory import Route, Trajectory

from .maps import REPO_ROOT
from .terrain import fbm_2d

MAP = Path("scenarios/maps/terrain_nav_geo_fbm.tif")
TRACK = Path("scenarios/tracks/terrain_nav_s_turn.csv")
TRACK_ORIGIN = GeoPoint(lat_deg=45.0, lon_deg=7.0, alt_m=0.0)
#: the map's north-west corner and pixel size, deg
MAP_NORTH, MAP_WEST, MAP_PIXEL_DEG, MAP_SHAPE = 45.22, 6.72, 0.001, (380, 560)


def s_turn_route() -> Route:
    return Route.model_validate(
        {
            "start": {"position_m": [0.0, 0.0, 1000.0], "heading_deg": 30.0, "speed_mps": 200.0},
            "legs": [{"duration_s": 40.0}, {"duration_s": 30.0, "turn_rate_dps": 3.0}, {"duration_s": 60.0}],
        }
    )


def write_track(root: Path = REPO_ROOT, seed: int = 16) -> Path:
    t = np.arange(0.0, 130.0 + 1e-9, 0.5)
    pos = Trajectory.from_route(s_turn_route()).states(t).position_m
    pos = pos + np.random.default_rng(seed).normal(0.0, 2.0, pos.shape)
    geo = LocalFrame(TRACK_ORIGIN).to_geodetic(pos)
    out = root / TRACK
    out.parent.mkdir(parents=True, exist_ok=True)
    comment = (
        "fixstream example track (services/terrain_nav/examples.py): 200 m/s, heading 30 deg, 3 deg/s right turn\n"
        "of 30 s from t = 40 s, level at 1000 m; 2 Hz, 2 m GNSS-like noise per axis; WGS84 latitude, longitude,\n"
        "height above the ellipsoid; the flight starts at 45.0 N 7.0 E (0 m ellipsoid height + 1000 m)"
    )
    return write_track_csv(out, t, {"lat_deg": geo[:, 0], "lon_deg": geo[:, 1], "alt_m": geo[:, 2]}, comment)


def write_map(root: Path = REPO_ROOT, seed: int = 16) -> Path:
    import rasterio
    from affine import Affine

    h = fbm_2d(MAP_SHAPE, np.random.default_rng(seed), H=0.6, rms_inc_m=10.0)
    h = np.round(h - h.min() + 200.0).astype(np.int16)
    out = root / MAP
    out.parent.mkdir(parents=True, exist_ok=True)
    with rasterio.open(
        out, "w", driver="GTiff", height=MAP_SHAPE[0], width=MAP_SHAPE[1], count=1, dtype="int16",
        crs="EPSG:4326", transform=Affine(MAP_PIXEL_DEG, 0.0, MAP_WEST, 0.0, -MAP_PIXEL_DEG, MAP_NORTH),
        nodata=-32768, compress="deflate", predictor=2,
    ) as dst:  # fmt: skip
        dst.write(h, 1)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m services.terrain_nav.examples", description=__doc__)
    parser.add_argument("--root", type=Path, default=REPO_ROOT, help="repository root to write under")
    args = parser.parse_args(argv)
    for p in (write_map(args.root), write_track(args.root)):
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
