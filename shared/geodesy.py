"""Geodetic <-> local east/north/up, exactly, at an origin on WGS84 (PROJ), for every part of the stack.

A scenario's frame with a geodetic ``origin`` is the **topocentric** (local tangent-plane) Cartesian frame at
that origin: east, north and up along the ellipsoid's axes at the origin, up along its normal there. PROJ's
``cart`` + ``topocentric`` pipeline converts geodetic -> Earth-centred Cartesian (WGS84) -> this frame and back:
an exact rigid transform, no flat-earth arcs. A level flight 100 km from the origin therefore shows the Earth's
curvature (~785 m below the tangent plane), as it must in a Cartesian frame, and a point converted one way and
back is where it started (to PROJ's round-off, far below a millimetre).

Who uses it: the player's recorded tracks (geodetic rows -> the scenario frame) and the Foxglove map channels
(the scenario frame -> latitude, longitude, height), so that a recorded track shows on the map where it was
recorded.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


class GeodeticPoint(Protocol):
    """Anything with a WGS84 latitude and longitude (deg) and a height above the ellipsoid (m)."""

    @property
    def lat_deg(self) -> float: ...

    @property
    def lon_deg(self) -> float: ...

    @property
    def alt_m(self) -> float: ...


class LocalFrame:
    """Exact geodetic <-> local east/north/up conversion at an origin on WGS84 (PROJ ``cart`` + ``topocentric``)."""

    def __init__(self, origin: GeodeticPoint) -> None:
        from pyproj import Transformer  # here, not at import: a process that never converts never loads PROJ

        self.origin = origin
        self._t = Transformer.from_pipeline(
            "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad +step +proj=cart +ellps=WGS84 "
            f"+step +proj=topocentric +ellps=WGS84 +lat_0={float(origin.lat_deg)!r} "
            f"+lon_0={float(origin.lon_deg)!r} +h_0={float(origin.alt_m)!r}"
        )

    def to_enu(self, lat_deg: F64, lon_deg: F64, alt_m: F64) -> F64:
        """(n, 3) [east, north, up] m of geodetic points."""
        e, n, u = self._t.transform(np.asarray(lon_deg, float), np.asarray(lat_deg, float), np.asarray(alt_m, float))
        return np.column_stack([np.atleast_1d(e), np.atleast_1d(n), np.atleast_1d(u)])

    def to_geodetic(self, enu: F64) -> F64:
        """(n, 3) [lat_deg, lon_deg, alt_m] of local [east, north, up] points."""
        enu = np.atleast_2d(np.asarray(enu, dtype=np.float64))
        lon, lat, h = self._t.transform(enu[:, 0], enu[:, 1], enu[:, 2], direction="INVERSE")
        return np.column_stack([np.atleast_1d(lat), np.atleast_1d(lon), np.atleast_1d(h)])
