"""Reference elevation maps (digest §1.6, §5.2): in-memory model, loaders and load-time statistics.

* ``.npy`` with a JSON sidecar ``{x0, z0, cell, datum, nodata, axes}`` (:func:`load_npy`, :func:`save_npy`);
* GeoTIFF through rasterio (:func:`load_geotiff`) in **any CRS**: a raster with square pixels in a projected
  CRS whose size divides the cell size is block-averaged (§1.6); any other raster (geographic CRS, rotated,
  non-square or non-dividing pixels) is reprojected with rasterio/PROJ to square cells of ``cell_m`` in a
  local transverse Mercator projection centred on the raster (see :func:`load_geotiff`). Axis 0 points along
  +x (north by default).

Precomputed at load: the void mask, D1 (mean-square adjacent-cell height change, m^2) and the terrain
variance sigma_t^2 (m^2); the zone mask for a hypothesis half-width is computed on first use and cached.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from .geometry import F64, Bool, cell_index, window_all


@dataclass
class ReferenceMap:
    """A DEM on a regular grid: axis 0 = x (longitudinal), axis 1 = z (transverse), heights in metres.

    Voids are NaN in :attr:`dem` (the loaders turn ``nodata`` into NaN). ``x0_m, z0_m`` is the corner of
    cell (0, 0), ``cell_m`` the cell size.
    """

    dem: F64
    x0_m: float = 0.0
    z0_m: float = 0.0
    cell_m: float = 125.0
    datum: str = ""
    nodata: float | None = None
    crs: str = ""  #: the projected CRS of the map frame (PROJ string or WKT); "" for a synthetic map
    x_axis: Literal["north", "east"] = "north"  #: which CRS axis the map's x is (z is the other one)
    void: Bool = field(init=False)
    D1_m2: float = field(init=False)
    sigma_t2_m2: float = field(init=False)
    _zones: dict[tuple[int, int], Bool] = field(init=False, default_factory=dict, repr=False)
    _slope: tuple[F64, F64] | None = field(init=False, default=None, repr=False)

    def __post_init__(self) -> None:
        dem = np.array(self.dem, dtype=np.float64)
        if dem.ndim != 2 or min(dem.shape) < 2:
            raise ValueError(f"a map needs a 2-D grid of at least 2x2 cells, got shape {dem.shape}")
        if not (self.cell_m > 0 and math.isfinite(self.cell_m)):
            raise ValueError("cell_m must be a positive finite size")
        if self.nodata is not None:
            dem[dem == self.nodata] = np.nan
        dem[~np.isfinite(dem)] = np.nan
        dem.setflags(write=False)
        self.dem = dem
        self.void = np.isnan(dem)
        self.D1_m2, self.sigma_t2_m2 = roughness(dem)

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.dem.shape[0]), int(self.dem.shape[1]))

    def cell_of(self, x_m: float, z_m: float) -> tuple[int, int]:
        """Cell (I, J) containing the point (may lie outside the map)."""
        return cell_index(x_m, self.x0_m, self.cell_m), cell_index(z_m, self.z0_m, self.cell_m)

    def centre_of(self, I: int, J: int) -> tuple[float, float]:  # noqa: E741 - cell index
        """Map coordinates of the centre of cell (I, J), m."""
        return self.x0_m + (I + 0.5) * self.cell_m, self.z0_m + (J + 0.5) * self.cell_m

    def zone_mask(self, M_x: int, M_z: int) -> Bool:
        """INS cells whose whole hypothesis patch ``[I-M_x, I+M_x] x [J-M_z, J+M_z]`` is on the map, void-free."""
        key = (M_x, M_z)
        if key not in self._zones:
            self._zones[key] = window_all(~self.void, -M_x, M_x, -M_z, M_z)
        return self._zones[key]

    def bilinear_zone_mask(self, M_x: int, M_z: int) -> Bool:
        """Anchor cells (I0, J0) for which bilinear reads over every hypothesis stay on the map (base mode)."""
        key = (-M_x - 1, -M_z - 1)
        if key not in self._zones:
            self._zones[key] = window_all(~self.void, -M_x, M_x + 1, -M_z, M_z + 1)
        return self._zones[key]

    def slope(self) -> tuple[F64, F64]:
        """Terrain slope (dH/dx, dH/dz) per cell, m/m: central differences, one-sided at the edges, NaN next to a
        void. Computed on first use and cached."""
        if self._slope is None:
            gx: F64 = np.gradient(self.dem, self.cell_m, axis=0)
            gz: F64 = np.gradient(self.dem, self.cell_m, axis=1)
            gx.setflags(write=False)
            gz.setflags(write=False)
            self._slope = (gx, gz)
        return self._slope

    def L_zk(self, source: Literal["D1", "sigma_t2"] = "D1") -> float:
        """Correction-zone parameter L_zk (§2.12): D1 (default) or the terrain variance, m^2."""
        return self.D1_m2 if source == "D1" else self.sigma_t2_m2


def roughness(dem: F64) -> tuple[float, float]:
    """(D1, sigma_t^2) of a DEM with NaN voids (§2.12).

    D1 = mean over cells with both forward neighbours of 0.5*[(h[I+1,J]-h[I,J])^2 + (h[I,J+1]-h[I,J])^2].
    """
    dx = dem[1:, :-1] - dem[:-1, :-1]
    dz = dem[:-1, 1:] - dem[:-1, :-1]
    d = 0.5 * (dx * dx + dz * dz)
    ok = np.isfinite(d)
    D1 = float(d[ok].mean()) if ok.any() else 0.0
    h = dem[np.isfinite(dem)]
    sigma_t2 = float(h.var()) if h.size else 0.0
    return D1, sigma_t2


def block_average(a: F64, factor: int) -> F64:
    """Mean over ``factor x factor`` blocks (trailing partial blocks dropped; a block with a NaN is NaN)."""
    if factor < 1:
        raise ValueError("factor must be >= 1")
    if factor == 1:
        return np.asarray(a, dtype=np.float64)
    n_i, n_j = a.shape[0] // factor, a.shape[1] // factor
    if n_i < 1 or n_j < 1:
        raise ValueError(f"grid {a.shape} is smaller than one {factor}x{factor} block")
    b = np.asarray(a[: n_i * factor, : n_j * factor], dtype=np.float64)
    out: F64 = b.reshape(n_i, factor, n_j, factor).mean(axis=(1, 3))
    return out


# --- .npy + JSON sidecar -------------------------------------------------------------------------------------


def save_npy(ref: ReferenceMap, path: str | Path) -> Path:
    """Write ``<path>.npy`` and the sidecar ``<path>.json``; returns the .npy path."""
    p = Path(path).with_suffix(".npy")
    dem = np.array(ref.dem)
    nodata = ref.nodata if ref.nodata is not None else -32768.0
    dem[np.isnan(dem)] = nodata
    np.save(p, dem)
    meta = {
        "x0": ref.x0_m,
        "z0": ref.z0_m,
        "cell": ref.cell_m,
        "datum": ref.datum,
        "nodata": nodata,
        "axes": ["x", "z"],
    }
    if ref.crs:
        meta["crs"] = ref.crs
        meta["x_axis"] = ref.x_axis
    p.with_suffix(".json").write_text(json.dumps(meta, indent=2) + "\n")
    return p


def load_npy(path: str | Path, cell_m: float | None = None) -> ReferenceMap:
    """Load ``<path>.npy`` with its JSON sidecar; optionally block-average to ``cell_m``.

    ``axes`` is ``["x", "z"]`` (axis 0 along x) or ``["z", "x"]`` (transposed on load).
    """
    p = Path(path).with_suffix(".npy")
    meta = json.loads(p.with_suffix(".json").read_text())
    missing = {"x0", "z0", "cell"} - set(meta)
    if missing:
        raise ValueError(f"{p.with_suffix('.json')}: sidecar lacks {sorted(missing)}")
    dem = np.load(p, allow_pickle=False).astype(np.float64)
    axes = meta.get("axes", ["x", "z"])
    if list(axes) == ["z", "x"]:
        dem = dem.T
    elif list(axes) != ["x", "z"]:
        raise ValueError(f"axes must be ['x','z'] or ['z','x'], got {axes}")
    nodata = meta.get("nodata")
    if nodata is not None:
        dem[dem == float(nodata)] = np.nan
    cell = float(meta["cell"])
    if cell_m is not None and not math.isclose(cell_m, cell):
        dem = block_average(dem, _factor(cell_m, cell))
        cell = cell_m
    x_axis = meta.get("x_axis", "north")
    if x_axis not in ("north", "east"):
        raise ValueError(f"x_axis must be 'north' or 'east', got {x_axis!r}")
    return ReferenceMap(
        dem=dem,
        x0_m=float(meta["x0"]),
        z0_m=float(meta["z0"]),
        cell_m=cell,
        datum=str(meta.get("datum", "")),
        crs=str(meta.get("crs", "")),
        x_axis=x_axis,
    )


def _factor(cell_m: float, pixel_m: float) -> int:
    f = cell_m / pixel_m
    k = round(f)
    if k < 1 or abs(f - k) > 1e-6 * max(1.0, f):
        raise ValueError(f"cell size {cell_m} m is not an integer multiple of the pixel size {pixel_m} m")
    return int(k)


# --- GeoTIFF (rasterio) ----------------------------------------------------------------------------------------


def local_tm_crs(lat_deg: float, lon_deg: float) -> str:
    """A transverse Mercator projection on WGS84 centred at (lat, lon), scale 1 on its central meridian (PROJ)."""
    return f"+proj=tmerc +lat_0={lat_deg:.9f} +lon_0={lon_deg:.9f} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"


def _needs_reprojection(tr: object, crs: object, cell_m: float) -> bool:
    a, b, d, e = tr.a, tr.b, tr.d, tr.e  # type: ignore[attr-defined]
    if abs(b) > 0 or abs(d) > 0 or not math.isclose(abs(a), abs(e), rel_tol=1e-9):
        return True
    if crs is not None and not crs.is_projected:  # type: ignore[attr-defined]
        return True
    f = cell_m / abs(a)
    return round(f) < 1 or abs(f - round(f)) > 1e-6 * max(1.0, f)


def load_geotiff(
    path: str | Path, cell_m: float, x_axis: Literal["north", "east"] = "north", band: int = 1
) -> ReferenceMap:
    """Load a single-band GeoTIFF in any CRS as a map of square ``cell_m`` cells.

    * **Projected CRS, square unrotated pixels whose size divides** ``cell_m``: block averaging (§1.6), the
      map frame is the raster's own CRS.
    * **Anything else** is reprojected with ``rasterio.warp.reproject`` (PROJ) onto a north-up grid of
      ``cell_m`` cells whose edges are multiples of ``cell_m``: in the raster's own CRS if it is projected (a
      rotated or non-square raster, a pixel size that does not divide ``cell_m``), else (a geographic CRS
      such as EPSG:4326) in a transverse Mercator projection on WGS84 centred on the raster's centre
      (:func:`local_tm_crs`; scale error < 1e-4 within 90 km of the centre). Resampling is ``average`` (the
      mean of the source pixels a cell covers, the block average's counterpart) when the source pixels are
      finer than the cell, ``bilinear`` otherwise.
      Source nodata and pixels outside the raster become voids. The map's ``crs`` is that projection, so
      geodetic points (waypoints, tracks) convert to the map frame exactly with pyproj.

    ``x_axis="north"``: x = northing, z = easting (the Russian x-north, y-up, z-east frame);
    ``x_axis="east"``: x = easting, z = northing.
    """
    import rasterio

    with rasterio.open(path) as src:
        tr = src.transform
        src_crs = src.crs
        if _needs_reprojection(tr, src_crs, cell_m):
            data, x0w, y0s, crs_out = _reproject(src, band, cell_m, src_crs is not None and src_crs.is_projected)
            pixel = cell_m
            flip_rows, flip_cols = True, False
        else:
            data = src.read(band, masked=True).astype(np.float64).filled(np.nan)
            x0w, y0s, _east, _north = src.bounds
            crs_out = src_crs.to_string() if src_crs is not None else ""
            pixel = abs(tr.a)
            flip_rows, flip_cols = tr.e < 0, tr.a < 0
        datum = src_crs.to_string() if src_crs is not None else ""
    if flip_rows:  # rows run north -> south: flip so that axis 0 increases northwards
        data = data[::-1, :]
    if flip_cols:
        data = data[:, ::-1]
    if x_axis == "north":
        arr, x0, z0 = data, y0s, x0w
    else:
        arr, x0, z0 = data.T, x0w, y0s
    arr = block_average(arr, _factor(cell_m, pixel))
    return ReferenceMap(
        dem=arr, x0_m=float(x0), z0_m=float(z0), cell_m=float(cell_m), datum=datum, crs=crs_out, x_axis=x_axis
    )


def _reproject(src: object, band: int, cell_m: float, keep_crs: bool) -> tuple[F64, float, float, str]:
    """Reproject band ``band`` of an open rasterio dataset to a north-up grid of ``cell_m`` cells, in its own
    (projected) CRS if ``keep_crs``, else in a local TM projection centred on the raster."""
    from pyproj import CRS, Transformer
    from rasterio.warp import Resampling, reproject, transform_bounds

    if src.crs is None:  # type: ignore[attr-defined]
        raise ValueError("a raster without a CRS cannot be reprojected: give it a CRS (or square projected pixels)")
    if keep_crs:
        crs = src.crs.to_string()  # type: ignore[attr-defined]
    else:
        lon_w, lat_s, lon_e, lat_n = transform_bounds(src.crs, "EPSG:4326", *src.bounds, densify_pts=21)  # type: ignore[attr-defined]
        crs = local_tm_crs(0.5 * (lat_s + lat_n), 0.5 * (lon_w + lon_e))
    w, s, e, n = transform_bounds(src.crs, CRS.from_user_input(crs), *src.bounds, densify_pts=21)  # type: ignore[attr-defined]
    x0, y0 = math.floor(w / cell_m) * cell_m, math.floor(s / cell_m) * cell_m
    width, height = math.ceil((e - x0) / cell_m), math.ceil((n - y0) / cell_m)
    # source pixel size in metres at the centre, to choose the resampling
    to_m = Transformer.from_crs(src.crs, CRS.from_user_input(crs), always_xy=True)  # type: ignore[attr-defined]
    tr = src.transform  # type: ignore[attr-defined]
    u, v = src.width / 2.0, src.height / 2.0  # type: ignore[attr-defined]
    cx, cy = tr.c + tr.a * u + tr.b * v, tr.f + tr.d * u + tr.e * v
    px, py = cx + tr.a + tr.b, cy + tr.d + tr.e
    (ax, ay), (bx, by) = to_m.transform(cx, cy), to_m.transform(px, py)
    pixel_m = math.sqrt(abs((bx - ax) * (by - ay)))
    from affine import Affine

    dst_transform = Affine(cell_m, 0.0, x0, 0.0, -cell_m, y0 + height * cell_m)
    dst = np.full((height, width), np.nan, dtype=np.float64)
    source = src.read(band, masked=True).astype(np.float64).filled(np.nan)  # type: ignore[attr-defined]
    reproject(
        source=source,
        destination=dst,
        src_transform=tr,
        src_crs=src.crs,  # type: ignore[attr-defined]
        src_nodata=np.nan,
        dst_transform=dst_transform,
        dst_crs=crs,
        dst_nodata=np.nan,
        resampling=Resampling.average if pixel_m <= cell_m else Resampling.bilinear,
    )
    return dst, float(x0), float(y0), crs


# --- any supported file ---------------------------------------------------------------------------------------

#: the repository root: relative map paths that do not exist from the working directory are tried here
REPO_ROOT = Path(__file__).resolve().parents[2]
GEOTIFF_SUFFIXES = (".tif", ".tiff")


def resolve_map_path(path: str | Path) -> Path:
    """An absolute path as is; a relative one from the working directory, else from the repository root."""
    p = Path(path)
    if p.is_absolute():
        return p
    for base in (Path.cwd(), REPO_ROOT):
        q = base / p
        if q.exists() or q.with_suffix(".npy").exists():
            return q
    return Path.cwd() / p


def load_map(path: str | Path, cell_m: float | None = None, x_axis: Literal["north", "east"] = "north") -> ReferenceMap:
    """Load a reference map by its suffix: GeoTIFF (``.tif``/``.tiff``, needs ``cell_m``) or ``.npy`` + sidecar.

    Relative paths are resolved by :func:`resolve_map_path`. Raises ``FileNotFoundError`` or ``ValueError``
    with the path in the message.
    """
    p = resolve_map_path(path)
    if p.suffix.lower() in GEOTIFF_SUFFIXES:
        if cell_m is None:
            raise ValueError(f"{p}: a GeoTIFF map needs the cell size to block-average to (cell_m)")
        if not p.exists():
            raise FileNotFoundError(f"map file {p} does not exist")
        return load_geotiff(p, cell_m, x_axis)
    npy = p.with_suffix(".npy")
    for f in (npy, npy.with_suffix(".json")):
        if not f.exists():
            raise FileNotFoundError(f"map file {f} does not exist (a .npy map needs its .json sidecar)")
    return load_npy(npy, cell_m)
