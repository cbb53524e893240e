"""Reference elevation maps (digest §1.6, §5.2): in-memory model, loaders and load-time statistics.

* ``.npy`` with a JSON sidecar ``{x0, z0, cell, datum, nodata, axes}`` (:func:`load_npy`, :func:`save_npy`);
* GeoTIFF through rasterio (optional dependency, :func:`load_geotiff`): square pixels in a projected CRS,
  block-averaged to the cell size and oriented so that axis 0 points along +x.

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
    void: Bool = field(init=False)
    D1_m2: float = field(init=False)
    sigma_t2_m2: float = field(init=False)
    _zones: dict[tuple[int, int], Bool] = field(init=False, default_factory=dict, repr=False)

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
    return ReferenceMap(
        dem=dem, x0_m=float(meta["x0"]), z0_m=float(meta["z0"]), cell_m=cell, datum=str(meta.get("datum", ""))
    )


def _factor(cell_m: float, pixel_m: float) -> int:
    f = cell_m / pixel_m
    k = round(f)
    if k < 1 or abs(f - k) > 1e-6 * max(1.0, f):
        raise ValueError(f"cell size {cell_m} m is not an integer multiple of the pixel size {pixel_m} m")
    return int(k)


# --- GeoTIFF (rasterio) ----------------------------------------------------------------------------------------


def load_geotiff(
    path: str | Path, cell_m: float, x_axis: Literal["north", "east"] = "north", band: int = 1
) -> ReferenceMap:
    """Load a single-band GeoTIFF in a projected CRS and block-average it to ``cell_m``.

    ``x_axis="north"``: x = northing, z = easting (the Russian x-north, y-up, z-east frame);
    ``x_axis="east"``: x = easting, z = northing. Pixels must be square and the raster not rotated.
    """
    import rasterio

    with rasterio.open(path) as src:
        tr = src.transform
        if abs(tr.b) > 0 or abs(tr.d) > 0:
            raise ValueError("rotated rasters are not supported: rotate upstream")
        if not math.isclose(abs(tr.a), abs(tr.e), rel_tol=1e-9):
            raise ValueError(f"pixels must be square, got {abs(tr.a)} x {abs(tr.e)}")
        if src.crs is not None and not src.crs.is_projected:
            raise ValueError(f"the raster CRS {src.crs} is not projected (metres needed)")
        data = src.read(band, masked=True).astype(np.float64).filled(np.nan)
        west, south, _east, _north = src.bounds
        datum = src.crs.to_string() if src.crs is not None else ""
    pixel = abs(tr.a)
    if tr.e < 0:  # rows run north -> south: flip so that axis 0 increases northwards
        data = data[::-1, :]
    if tr.a < 0:
        data = data[:, ::-1]
    if x_axis == "north":
        arr, x0, z0 = data, south, west
    else:
        arr, x0, z0 = data.T, west, south
    arr = block_average(arr, _factor(cell_m, pixel))
    return ReferenceMap(dem=arr, x0_m=float(x0), z0_m=float(z0), cell_m=float(cell_m), datum=datum)


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
