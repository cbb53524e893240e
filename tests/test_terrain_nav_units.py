"""Deterministic unit tests of the terrain navigator's building blocks (digest 001).

Reference values come from the digest's definitions or from independent computations in the test
(scipy's matrix exponential, filterpy's Kalman filter, brute-force sums), never from the implementation.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
from filterpy.kalman import KalmanFilter

from services.terrain_nav import conditions as cond
from services.terrain_nav.filter import KalmanBank
from services.terrain_nav.geometry import HypothesisGrid, bilinear, cell_index, window_all
from services.terrain_nav.maps import ReferenceMap, block_average, load_npy, roughness, save_npy
from services.terrain_nav.models import measurement_variance, process_noise, transition
from services.terrain_nav.output import cell_centre_terms, grid_covariance, quadratic_hessian
from services.terrain_nav.resampler import CellMeasurement, CellResampler
from services.terrain_nav.terrain import TERRAIN_TYPES, fbm_1d, fbm_2d, make_terrain, rms_increment
from services.terrain_nav.window import SegmentedWindow

# --- models (§1.4) ---------------------------------------------------------------------------------------------

A_CONT = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # d(dV)/dt = da, d(dh)/dt = dV
G = np.array([[1.0], [0.0], [0.0]])  # white noise drives da


@pytest.mark.parametrize("T", [0.05, 0.625, 1.7, 5.0])
def test_transition_is_the_exact_discretisation_of_the_triple_integrator(T: float) -> None:
    np.testing.assert_allclose(transition(T, "exact"), scipy.linalg.expm(A_CONT * T), rtol=0, atol=1e-12)
    euler = transition(T, "euler")
    assert euler[2, 0] == 0.0 and euler[2, 1] == T and euler[1, 0] == T  # rows 1-2 legible [P], row 3 = [0 T 1]


@pytest.mark.parametrize("T", [0.05, 0.625, 3.0])
def test_process_noise_matches_van_loan(T: float) -> None:
    q_a = 2.5e-3
    n = 3
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A_CONT
    M[:n, n:] = G @ G.T * q_a
    M[n:, n:] = A_CONT.T
    E = scipy.linalg.expm(M * T)
    Phi = E[n:, n:].T
    Q_ref = Phi @ E[:n, n:]
    np.testing.assert_allclose(process_noise(T, q_a), Q_ref, rtol=1e-9, atol=1e-18)
    assert process_noise(T, 0.0, q_h=0.4)[2, 2] == pytest.approx(0.4 * T)


def test_measurement_variance_of_the_digest() -> None:
    # R_k = sigma_v^2/n_k + sigma_map^2 + c_q D1 = 4/12 + 9 + 0.3*150
    assert measurement_variance(12, 2.0, 3.0, 0.3, 150.0) == pytest.approx(4 / 12 + 9 + 45)


# --- the vectorised KF bank against independent filterpy filters (§2.2, S4) ---------------------------------


def test_kalman_bank_equals_one_filterpy_filter_per_hypothesis() -> None:
    rng = np.random.default_rng(3)
    shape = (5, 7)
    P0 = [0.01**2, 1.0**2, 100.0**2]
    q_a = 1e-4
    bank = KalmanBank(shape, P0, "exact", q_a, 0.0)
    filters = []
    for _ in range(shape[0] * shape[1]):
        kf = KalmanFilter(dim_x=3, dim_z=1)
        kf.x = np.zeros((3, 1))
        kf.P = np.diag(P0)
        kf.H = np.array([[0.0, 0.0, 1.0]])
        filters.append(kf)
    times = np.cumsum(np.concatenate([[0.0], rng.uniform(0.3, 1.2, 24)]))
    for k, t in enumerate(times):
        patch = rng.normal(500.0, 30.0, shape)
        c = rng.normal(-450.0, 5.0)
        R = float(rng.uniform(5.0, 60.0))
        bank.predict(float(t))
        nu = bank.innovation(patch, c).copy()
        bank.update(nu, R)
        for idx, kf in enumerate(filters):
            if k > 0:
                T = float(t - times[k - 1])
                kf.predict(F=transition(T, "exact"), Q=process_noise(T, q_a))
            kf.update(np.array([[patch.flat[idx] + c]]), R=R)
            assert nu.flat[idx] == pytest.approx(float(kf.y[0, 0]), rel=1e-12, abs=1e-9)
        states = np.stack([kf.x[:, 0] for kf in filters], axis=1).reshape(3, *shape)
        np.testing.assert_allclose(bank.x, states, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(bank.P, filters[0].P, rtol=1e-9, atol=1e-12)
        assert np.allclose(bank.P, bank.P.T) and np.all(np.linalg.eigvalsh(bank.P) > 0)


# --- geometry (§1.2, §2.1) -----------------------------------------------------------------------------------


def test_cell_index_is_floor_of_the_offset() -> None:
    assert cell_index(0.0, 0.0, 125.0) == 0
    assert cell_index(124.999, 0.0, 125.0) == 0
    assert cell_index(125.0, 0.0, 125.0) == 1
    assert cell_index(-0.001, 0.0, 125.0) == -1
    assert cell_index(1000.0, 250.0, 125.0) == 6


def test_hypothesis_grid_offsets() -> None:
    g = HypothesisGrid(25, 25)
    assert g.shape == (51, 51) and g.size == 2601
    assert g.offset_of(0, 50) == (-25, 25)
    assert g.index_of(0, 0) == (25, 25)


def test_window_all_equals_brute_force() -> None:
    rng = np.random.default_rng(5)
    ok = rng.uniform(size=(30, 22)) > 0.03
    out = window_all(ok, -3, 4, -2, 2)
    for ci in range(30):
        for cj in range(22):
            inside = ci - 3 >= 0 and ci + 4 < 30 and cj - 2 >= 0 and cj + 2 < 22
            expect = inside and bool(ok[ci - 3 : ci + 5, cj - 2 : cj + 3].all())
            assert out[ci, cj] == expect


def test_bilinear_hits_cell_centres_and_is_linear_between() -> None:
    g = np.arange(20.0).reshape(4, 5) ** 1.5
    assert bilinear(g, np.array([2.0]), np.array([3.0]))[0] == pytest.approx(g[2, 3])
    mid = bilinear(g, np.array([1.25]), np.array([2.5]))[0]
    expect = 0.75 * (0.5 * g[1, 2] + 0.5 * g[1, 3]) + 0.25 * (0.5 * g[2, 2] + 0.5 * g[2, 3])
    assert mid == pytest.approx(expect)


# --- maps (§1.6, §5.2, §2.12) ------------------------------------------------------------------------------------


def test_roughness_D1_and_sigma_t_by_brute_force() -> None:
    rng = np.random.default_rng(2)
    h = rng.normal(300.0, 20.0, (9, 7))
    h[4, 3] = np.nan
    terms = []
    for ci in range(8):
        for cj in range(6):
            a, b, c = h[ci, cj], h[ci + 1, cj], h[ci, cj + 1]
            if np.isfinite([a, b, c]).all():
                terms.append(0.5 * ((b - a) ** 2 + (c - a) ** 2))
    D1, s2 = roughness(h)
    assert pytest.approx(np.mean(terms), rel=1e-12) == D1
    assert s2 == pytest.approx(np.nanvar(h), rel=1e-12)


def test_zone_mask_needs_the_whole_patch_on_the_map_and_void_free() -> None:
    dem = np.full((40, 30), 100.0)
    dem[20, 5] = np.nan
    ref = ReferenceMap(dem=dem, cell_m=125.0)
    zone = ref.zone_mask(5, 4)
    assert not zone[4, 15] and zone[5, 15] and zone[34, 15] and not zone[35, 15]
    assert not zone[30, 3] and zone[30, 4] and zone[30, 25] and not zone[30, 26]
    assert not zone[20, 9] and not zone[15, 9] and zone[14, 9] and zone[20, 10]  # patch touching the void


def test_npy_sidecar_round_trip_transposed_and_nodata(tmp_path) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(1)
    dem = rng.normal(500, 50, (12, 8))
    dem[3, 4] = np.nan
    ref = ReferenceMap(dem=dem, x0_m=1000.0, z0_m=-500.0, cell_m=125.0, datum="EGM96")
    p = save_npy(ref, tmp_path / "zone")
    back = load_npy(p)
    np.testing.assert_array_equal(np.isnan(back.dem), np.isnan(dem))
    np.testing.assert_allclose(back.dem[~np.isnan(dem)], dem[~np.isnan(dem)])
    assert (back.x0_m, back.z0_m, back.cell_m, back.datum) == (1000.0, -500.0, 125.0, "EGM96")
    # the same data stored with axes [z, x] loads transposed
    np.save(tmp_path / "t.npy", np.nan_to_num(dem, nan=-1.0).T)
    (tmp_path / "t.json").write_text('{"x0": 0, "z0": 0, "cell": 62.5, "nodata": -1.0, "axes": ["z", "x"]}')
    t = load_npy(tmp_path / "t.npy", cell_m=125.0)  # block-averaged 2x
    assert t.cell_m == 125.0 and t.dem.shape == (6, 4)
    assert t.dem[0, 0] == pytest.approx(dem[0:2, 0:2].mean())
    assert np.isnan(t.dem[1, 2])  # the block holding the void


def test_block_average_drops_partial_blocks() -> None:
    a = np.arange(7 * 9, dtype=float).reshape(7, 9)
    b = block_average(a, 3)
    assert b.shape == (2, 3)
    assert b[1, 2] == pytest.approx(a[3:6, 6:9].mean())


def test_geotiff_is_block_averaged_and_oriented_along_x(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import rasterio
    from affine import Affine

    from services.terrain_nav.maps import load_geotiff

    rows, cols, px = 80, 48, 31.25
    rng = np.random.default_rng(4)
    data = rng.normal(800.0, 40.0, (rows, cols)).astype(np.float32)
    data[5, 7] = -9999.0  # a nodata pixel in the north-west corner
    west, north = 500_000.0, 6_200_000.0
    path = tmp_path / "dem.tif"
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        height=rows,
        width=cols,
        count=1,
        dtype="float32",
        crs="EPSG:32637",
        transform=Affine(px, 0.0, west, 0.0, -px, north),
        nodata=-9999.0,
    ) as dst:
        dst.write(data, 1)
    ref = load_geotiff(path, cell_m=125.0, x_axis="north")
    assert ref.dem.shape == (20, 12) and ref.cell_m == 125.0
    assert ref.x0_m == pytest.approx(north - rows * px) and ref.z0_m == pytest.approx(west)
    south_up = data[::-1, :].astype(np.float64)  # row 0 = southernmost
    assert ref.dem[0, 0] == pytest.approx(south_up[0:4, 0:4].mean(), rel=1e-6)
    assert ref.dem[19, 11] == pytest.approx(south_up[76:80, 44:48].mean(), rel=1e-6)
    # pixel (row 5, col 7) from the north = south_up row 74 -> block (18, 1) is void
    assert np.isnan(ref.dem[18, 1]) and ref.void.sum() == 1
    east = load_geotiff(path, cell_m=125.0, x_axis="east")
    assert east.dem.shape == (12, 20) and east.x0_m == pytest.approx(west)
    assert east.dem[3, 2] == pytest.approx(ref.dem[2, 3])
    # a cell size the pixels do not divide: resampled (rasterio average) in the raster's own CRS, same area
    hundred = load_geotiff(path, cell_m=100.0)
    assert hundred.cell_m == 100.0 and hundred.crs == "EPSG:32637"
    assert hundred.x0_m % 100.0 == 0.0 and hundred.z0_m % 100.0 == 0.0
    # the mean height over the raster's area is kept: the cells are area means of N(800, 40) pixels, so the
    # grand means agree to a few standard errors (40/sqrt(3839 pixels) = 0.65 m; cut edge cells add a bit)
    assert float(np.nanmean(hundred.dem)) == pytest.approx(float(np.mean(data[data > -9000])), abs=3.0)


def test_geotiff_in_geographic_crs_is_reprojected_to_square_cells(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A DEM in EPSG:4326 (non-square metric pixels at 56 N) is reprojected to 125 m cells of a local TM projection.

    Independent check: the heights are a linear function of latitude and longitude, so the area mean over a
    cell equals the function at the cell's centre (converted back to lat/lon with pyproj) up to the pixel
    quantisation, |gradient| * half a pixel diagonal: 2000 m/deg * 0.0005 deg * 0.71 = 0.7 m.
    """
    import rasterio
    from affine import Affine
    from pyproj import Transformer

    from services.terrain_nav.maps import load_geotiff

    rows, cols, px = 240, 320, 0.0005  # 0.0005 deg = 55.6 m north-south, 31.1 m east-west at 56 N
    lat_n, lon_w = 56.1, 37.0
    lat = lat_n - (np.arange(rows) + 0.5) * px
    lon = lon_w + (np.arange(cols) + 0.5) * px
    height = 150.0 + 2000.0 * (lat[:, None] - 56.0) + 1000.0 * (lon[None, :] - 37.0)
    path = tmp_path / "geo.tif"
    with rasterio.open(
        path, "w", driver="GTiff", height=rows, width=cols, count=1, dtype="float64", crs="EPSG:4326",
        transform=Affine(px, 0.0, lon_w, 0.0, -px, lat_n), nodata=-9999.0,
    ) as dst:  # fmt: skip
        dst.write(height, 1)
    ref = load_geotiff(path, cell_m=125.0)
    assert ref.cell_m == 125.0 and "+proj=tmerc" in ref.crs and ref.x_axis == "north"
    # the extent: 0.12 deg of latitude = 13.4 km -> about 107 cells; 0.16 deg of longitude = 9.95 km -> ~80
    assert 106 <= ref.shape[0] <= 110 and 79 <= ref.shape[1] <= 83
    to_geo = Transformer.from_crs(ref.crs, "EPSG:4326", always_xy=True)
    inner = np.argwhere(~ref.void)
    checked = 0
    for I, J in inner[:: max(1, len(inner) // 300)]:  # noqa: E741 - cell indices
        x, z = ref.centre_of(int(I), int(J))
        # only cells whose whole area lies on the raster (edge cells are partial area means)
        if not (ref.x0_m + 125.0 < x - 62.5 and z - 62.5 > ref.z0_m + 125.0):
            continue
        if x + 125.0 > ref.x0_m + (ref.shape[0] - 1) * 125.0 or z + 125.0 > ref.z0_m + (ref.shape[1] - 1) * 125.0:
            continue
        lo, la = to_geo.transform(z, x)
        expected = 150.0 + 2000.0 * (la - 56.0) + 1000.0 * (lo - 37.0)
        assert ref.dem[I, J] == pytest.approx(expected, abs=0.8), (I, J)
        checked += 1
    assert checked > 100
    # a geodetic point goes to the map frame through the map's CRS (x = northing, z = easting)
    to_map = Transformer.from_crs("EPSG:4326", ref.crs, always_xy=True)
    e, n = to_map.transform(37.08, 56.05)
    I, J = ref.cell_of(n, e)  # noqa: E741
    assert 0 <= I < ref.shape[0] and 0 <= J < ref.shape[1] and not ref.void[I, J]


# --- synthetic terrain (§4, §5.2) -------------------------------------------------------------------------------


def test_fbm_is_scaled_to_the_rms_adjacent_cell_increment() -> None:
    rng = np.random.default_rng(11)
    h = fbm_2d((200, 101), rng, H=0.6, rms_inc_m=12.0)
    assert rms_increment(h) == pytest.approx(12.0, rel=1e-9)
    g = fbm_1d(300, rng, H=0.6, rms_inc_m=12.0)
    assert float(np.sqrt(np.mean(np.diff(g) ** 2))) == pytest.approx(12.0, rel=1e-9)


def test_fbm_structure_function_follows_the_hurst_exponent() -> None:
    # E[(h(x+L) - h(x))^2] ~ L^(2H) for fBm: the ratio at lags 4 and 1 is 4^(2H) = 5.28 for H = 0.6
    rng = np.random.default_rng(12)
    ratios = []
    for _ in range(8):
        h = fbm_2d((256, 256), rng, H=0.6, rms_inc_m=12.0)
        d1 = np.mean((h[1:, :] - h[:-1, :]) ** 2)
        d4 = np.mean((h[4:, :] - h[:-4, :]) ** 2)
        ratios.append(d4 / d1)
    assert np.mean(ratios) == pytest.approx(4 ** (2 * 0.6), rel=0.2)


def test_terrain_types_have_their_structure() -> None:
    rng = np.random.default_rng(13)
    shape = (120, 60)
    t = {k: make_terrain(k, shape, rng) for k in TERRAIN_TYPES}
    assert rms_increment(t["flat"]) == pytest.approx(0.3, rel=1e-9)
    assert np.ptp(t["ridge_z"], axis=0).max() == 0.0  # h = g(z): constant along x
    assert np.ptp(t["ridge_x"], axis=1).max() == 0.0  # h = g(x): constant across
    per = t["periodic"]
    np.testing.assert_allclose(per[10:, :], per[:-10, :], atol=1e-9)  # 10-cell along-track period
    assert np.ptp(per[:, 0] - per[:, 1]) == pytest.approx(0.0, abs=1e-9)  # g(z) adds a constant per column
    for h in t.values():
        assert np.all(np.isfinite(h)) and h.min() >= 500.0 - 1e-9


# --- AT-16: the reliability conditions with synthetic F arrays and histories (§2.5) -----------------------------


def _bowl(shape: tuple[int, int], centres: list[tuple[int, int]], floor: float = 100.0) -> np.ndarray:
    i, j = np.indices(shape)
    d2 = np.min([(i - a) ** 2 + (j - b) ** 2 for a, b in centres], axis=0)
    return floor + 400.0 * d2


def test_at16_c1_false_at_n_min() -> None:
    assert not cond.c1_enough_data(24, 24)  # N_valid = N_min: C1 is "N_valid > N_min"
    assert cond.c1_enough_data(25, 24)
    assert cond.c1_enough_data(24, 24, strict=False)


def test_at16_c2_false_at_twice_the_threshold() -> None:
    mu_F, L_zk, n = 0.5, 160.0, 30
    assert not cond.c2_fit(2 * mu_F * L_zk * n, n, mu_F, L_zk)  # F_min/N_valid = 2 mu_F L_zk
    assert cond.c2_fit(0.5 * mu_F * L_zk * n, n, mu_F, L_zk)
    assert not cond.c2_fit(0.0, 0, mu_F, L_zk)


def test_at16_c3_false_for_two_equal_minima_ten_cells_apart() -> None:
    F = _bowl((51, 51), [(25, 20), (25, 30)])
    a, b, fmin = cond.argmin_2d(F)
    assert (a, b) == (25, 20) and fmin == 100.0  # first in C order on a tie
    D = cond.d_max(F, a, b, mu3=1.5)
    assert pytest.approx(10.0) == D
    thr = cond.d_threshold(64, 24, 64, mu1=1.5, mu2=1.0)  # 1.5 + 64/64 = 2.5 cells
    assert thr == pytest.approx(2.5)
    assert not cond.c3_unique(D, thr)
    single = _bowl((51, 51), [(25, 20)])
    assert cond.c3_unique(cond.d_max(single, 25, 20, 1.5), thr)


def test_c3_counts_a_distant_secondary_minimum_not_only_the_connected_blob() -> None:
    F = _bowl((51, 51), [(10, 10)])
    F[40, 45] = 120.0  # an isolated near-minimum cell far away (within F_min*(1+mu3) = 250)
    assert cond.d_max(F, 10, 10, 1.5) == pytest.approx(math.hypot(30, 35))


def test_c3_phi_variants() -> None:
    assert cond.phi_of(32, 24, 64, "n_over_nmax") == pytest.approx(0.5)
    assert cond.phi_of(32, 24, 64, "nmax_over_n") == pytest.approx(2.0)
    assert cond.phi_of(34, 24, 64, "linear_min_max") == pytest.approx(0.25)


def test_at16_c4_false_for_an_alternating_argmin() -> None:
    # evaluations every N_p = 4 measurements; N_R = 8 keeps the entries with n > total - 8
    alternating = [(4, 3, -2), (8, 4, -2), (12, 3, -2), (16, 4, -2)]
    R = cond.r_min(alternating, 16, 8)
    assert R == 1 and not cond.c4_stable(R, 1.0)  # strict "< 1": the argmin moved
    assert cond.c4_stable(R, 1.0, strict=False)
    stable = [(4, 9, 1), (8, 3, -2), (12, 3, -2), (16, 3, -2)]
    assert cond.r_min(stable, 16, 8) == 0 and cond.c4_stable(0, 1.0)
    assert cond.r_min([(4, 9, 1), (8, 3, -2)], 16, 8) == 0  # entries at n <= total - N_R are out


# --- AT-10: segmented window equals the brute-force sum (§2.9 S3) -----------------------------------------------


@pytest.mark.parametrize("N_s", [1, 4, 8])
def test_at10_segmented_window_equals_brute_force(N_s: int) -> None:
    rng = np.random.default_rng(100 + N_s)
    shape, N_max = (6, 5), 20
    w: SegmentedWindow[int] = SegmentedWindow(shape, N_s, N_max, recompute_segments=7)
    arrays: dict[int, np.ndarray | None] = {}
    gap_left = 0
    for tick in range(600):
        if gap_left == 0 and rng.uniform() < 0.05:
            gap_left = int(rng.integers(1, 12))  # a run of excluded residuals (gaps)
        e2 = None if gap_left > 0 or rng.uniform() < 0.08 else rng.exponential(50.0, shape) * 10 ** rng.uniform(-2, 3)
        gap_left = max(gap_left - 1, 0)
        arrays[tick] = e2
        w.push(e2, tick)
        ticks = list(w.measq)
        assert ticks == list(range(ticks[0], tick + 1))  # the most recent consecutive measurements
        held = [arrays[k] for k in ticks if arrays[k] is not None]
        brute = np.sum(held, axis=0) if held else np.zeros(shape)
        np.testing.assert_allclose(w.F, brute, rtol=1e-9, atol=1e-9 * max(1.0, float(np.abs(brute).max())))
        assert w.N_valid == len(held)
        assert len(w.measq) == w.ticks
        if w.segq:  # exit condition: the oldest segment stays only if popping it would leave < N_max
            assert w.N_valid - w.segq[0].n < N_max


def test_window_n_valid_stays_between_n_max_and_n_max_plus_n_s_without_gaps() -> None:
    w: SegmentedWindow[int] = SegmentedWindow((3, 3), 8, 64)
    for tick in range(500):
        w.push(np.ones((3, 3)), tick)
        if tick >= 64:
            assert 64 <= w.N_valid <= 64 + 8 - 1
            assert w.stored_arrays() <= math.ceil(64 / 8) + 2


# --- AT-12: the cell-rate resampler (§2.9 S1) --------------------------------------------------------------------


def test_at12_resampler_one_measurement_per_crossed_cell() -> None:
    cell, V, fs = 125.0, 200.0, 20.0
    zone = np.zeros((80, 40), dtype=bool)
    zone[5:60, 5:35] = True  # correction zone: I in [5, 59]
    rs = CellResampler(0.0, 0.0, cell, zone, T_cell_max_s=5.0)
    rng = np.random.default_rng(9)
    t = np.arange(0.0, 40.0, 1.0 / fs)
    x = 2.3 * cell + V * t  # starts outside the zone (cell 2), enters at cell 5, leaves after cell 59
    z = np.full_like(t, 20.4 * cell)
    h_ra = rng.normal(300.0, 20.0, t.size)
    h_ins = rng.normal(1000.0, 1.0, t.size)
    valid = np.ones(t.size, dtype=bool)
    ix = np.floor(x / cell).astype(int)
    valid[ix == 12] = False  # a whole cell without a valid sample
    valid[(ix == 15) & (rng.uniform(size=t.size) < 0.5)] = False  # a partly invalid cell
    out = []
    for k in range(t.size):
        m, _ = rs.push(float(t[k]), float(x[k]), float(z[k]), float(h_ins[k]), float(h_ra[k]), bool(valid[k]), V)
        if m is not None:
            out.append(m)
    cells = [m.I for m in out]
    # cells 5..58 emitted once each except 12 (no valid sample); 59 is dropped at zone exit (flushed unemitted)
    assert cells == [c for c in range(5, 59) if c != 12]
    for m in out:
        sel = (ix == m.I) & valid
        assert m.n == int(sel.sum())
        assert m.h_ra == pytest.approx(h_ra[sel].mean(), rel=1e-12)
        assert m.h_ins == pytest.approx(h_ins[sel].mean(), rel=1e-12)
        assert m.t == pytest.approx(t[sel].mean(), rel=1e-12)
        assert m.x_mean == pytest.approx(x[sel].mean(), rel=1e-12)
        assert m.J == 20
    full = [m for m in out if m.I not in (5, 11, 13, 15, 16)]
    rate = 1.0 / np.diff([m.t for m in full if m.I > 16]).mean()
    assert rate == pytest.approx(V / cell, rel=0.01)  # 1.6 Hz


def test_resampler_emits_after_t_cell_max_at_low_speed() -> None:
    zone = np.ones((20, 20), dtype=bool)
    rs = CellResampler(0.0, 0.0, 125.0, zone, T_cell_max_s=5.0)
    out = []
    for k in range(241):  # 12 s at 20 Hz and 2 m/s: never leaves cell 4
        m, _ = rs.push(k * 0.05, 510.0 + 2.0 * k * 0.05, 600.0, 900.0, 400.0, True, 2.0)
        if m is not None:
            out.append(m)
    assert len(out) == 2 and all(m.I == 4 for m in out)
    assert out[0].t_last - out[0].t_first <= 5.0 + 1e-9


# --- output formation (§2.6) --------------------------------------------------------------------------------------


def _meas(ci: int, cj: int, x: float, z: float) -> CellMeasurement:
    return CellMeasurement(
        t=0.0, I=ci, J=cj, x_mean=x, z_mean=z, h_ins=0, h_ra=0, n=1, v_ground=0, vh_ins=None, t_first=0, t_last=0
    )


def test_cell_centre_conversion_removes_the_sub_cell_ins_position() -> None:
    ref = ReferenceMap(dem=np.zeros((10, 10)), x0_m=100.0, z0_m=-50.0, cell_m=125.0)
    # INS 30 m right of the cell centre across track, at the centre along track
    ms = [_meas(ci, 4, 100.0 + (ci + 0.5) * 125.0, -50.0 + 4.5 * 125.0 + 30.0) for ci in range(2, 8)]
    cx, cz = cell_centre_terms(ms, ref)
    assert cx == pytest.approx(0.0, abs=1e-9) and cz == pytest.approx(-30.0)


def test_quadratic_hessian_and_covariance_of_an_exact_quadratic() -> None:
    H = np.array([[800.0, 150.0], [150.0, 500.0]])  # m^2 per cell^2
    i, j = np.indices((7, 7)) - 3
    F = 60.0 * 30 + 0.5 * (H[0, 0] * i * i + 2 * H[0, 1] * i * j + H[1, 1] * j * j)
    np.testing.assert_allclose(quadratic_hessian(F[2:5, 2:5]), H, rtol=1e-12)
    cov, degenerate = grid_covariance(F, 3, 3, 30, 2.0, 125.0)
    sigma2 = F[3, 3] / 30
    expect = (2 * sigma2 * np.linalg.inv(H) + np.eye(2) / 12) * 125.0**2
    assert not degenerate
    np.testing.assert_allclose(cov, expect, rtol=1e-12)


def test_covariance_fallback_for_a_flat_minimum_and_an_edge_minimum() -> None:
    F = np.full((7, 7), 100.0)
    cov, degenerate = grid_covariance(F, 3, 3, 30, 2.0, 125.0)
    assert degenerate and np.allclose(cov, ((2.0 + 0.5) * 125.0) ** 2 * np.eye(2))
    _, degenerate = grid_covariance(_bowl((7, 7), [(0, 3)]), 0, 3, 30, 2.0, 125.0)
    assert degenerate
