"""Deterministic unit tests U1-U12 of digest 000 (section 4.1) for the LBL estimator core.

Expected values come from the digest or from independent computations in this file (a forward Kalman filter
written here for U10, closed-form geometry for U1-U5), never from the implementation's own output.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from schemas.lbl_nav import LblFix
from services.lbl_nav import geometry as geo
from services.lbl_nav import initiation
from services.lbl_nav.config import LblNavConfig
from services.lbl_nav.core import LblNavCore
from services.lbl_nav.filter import BufferedEpoch, HypothesisBank, HypothesisFilter
from services.lbl_nav.models import DrInterval, LinearRow, MotionModel
from services.lbl_nav.simulation import ScenarioSpec, SimBeacon, s1_spec, simulate

CFG = LblNavConfig()


def _reflect(x: float, y: float, alpha: float, px: float, py: float) -> tuple[float, float]:
    """Mirror of (x, y) across the line through (px, py) with azimuth alpha (independent of geometry.py)."""
    d = np.array([math.sin(alpha), math.cos(alpha)])
    v = np.array([x - px, y - py])
    m = 2.0 * (v @ d) * d - v
    return float(px + m[0]), float(py + m[1])


# ---- U1 -----------------------------------------------------------------------------------------------------------
def test_u1_rotation_puts_both_beacons_on_one_xbar_and_round_trips() -> None:
    rng = np.random.default_rng(1)
    for _ in range(200):
        x1, y1, x2, y2 = rng.uniform(-5000.0, 5000.0, 4)
        alpha = geo.baseline_azimuth(x1, y1, x2, y2)
        xb, yb = geo.rotate(np.array([x1, x2]), np.array([y1, y2]), alpha)
        assert abs(xb[1] - xb[0]) < 1e-9
        base = math.hypot(x2 - x1, y2 - y1)
        assert yb[1] - yb[0] > 0.0
        assert abs((yb[1] - yb[0]) - base) < 1e-9
        px, py = rng.uniform(-5000.0, 5000.0, 2)
        xr, yr = geo.rotate(px, py, alpha)
        bx, by = geo.unrotate(xr, yr, alpha)
        assert abs(bx - px) < 1e-9 and abs(by - py) < 1e-9


# ---- U2 -----------------------------------------------------------------------------------------------------------
def test_u2_pseudo_measurement_gives_the_true_along_baseline_coordinate() -> None:
    rng = np.random.default_rng(2)
    for _ in range(200):
        b = rng.uniform(-3000.0, 3000.0, (2, 2))
        bz = rng.uniform(0.0, 500.0, 2)
        p = rng.uniform(-3000.0, 3000.0, 2)
        z0 = rng.uniform(0.0, 300.0)
        ranges = [math.sqrt((b[j, 0] - p[0]) ** 2 + (b[j, 1] - p[1]) ** 2 + (bz[j] - z0) ** 2) for j in range(2)]
        alpha = geo.baseline_azimuth(b[0, 0], b[0, 1], b[1, 0], b[1, 1])
        _, yb = geo.rotate(b[:, 0], b[:, 1], alpha)
        _, y_true = geo.rotate(p[0], p[1], alpha)
        est = geo.ybar0_two(ranges[0], ranges[1], float(yb[0]), float(yb[1]), bz[0] - z0, bz[1] - z0)
        assert abs(est - float(y_true)) < 1e-6


# ---- U3 -----------------------------------------------------------------------------------------------------------
def test_u3_grid_has_12_nodes_off_the_baseline_spanning_plus_minus_dmax() -> None:
    cfg = LblNavConfig(D_max_m=1500.0, dx_nom_m=300.0)
    L = cfg.grid_nodes()
    assert L == 12
    xb = 123.4
    nodes = geo.grid_xbar(xb, cfg.D_max_m, L)
    assert nodes.size == 12
    assert np.min(np.abs(nodes - xb)) > 1.0
    assert abs(nodes[0] - (xb - 1500.0)) < 1e-9 and abs(nodes[-1] - (xb + 1500.0)) < 1e-9
    # the printed formula without the even rounding gives 11 nodes, one of them on the baseline
    assert LblNavConfig(grid_even=False).grid_nodes() == 11


# ---- U4 -----------------------------------------------------------------------------------------------------------
U4_BOUNDS = [(200.0, math.inf, 1e-6), (100.0, 200.0, 1e-3), (50.0, 100.0, 0.05), (20.0, 50.0, 1.5)]


def _noise_free_ranges(p: tuple[float, float], z0: float, beacons: list[tuple[str, float, float, float]]) -> list:
    out = []
    for bid, bx, by, bz in beacons:
        y = math.sqrt((bx - p[0]) ** 2 + (by - p[1]) ** 2 + (bz - z0) ** 2)
        out.append(initiation.LaunchRange(bid, bx, by, bz, y, y / CFG.c_nominal_mps))
    return out


def test_u4_noise_free_launch_finds_the_true_point_and_its_mirror() -> None:
    rng = np.random.default_rng(4)
    counts = dict.fromkeys(range(len(U4_BOUNDS)), 0)
    checked = 0
    while min(counts.values()) < 15:
        # the section 4.4 beacon pair (baseline 1500 m) moved rigidly; AUV within D_max of both, 20 m+ off the line
        bx1, by1 = rng.uniform(-1000.0, 1000.0, 2)
        base = 1500.0
        az = rng.uniform(-math.pi, math.pi)
        bx2, by2 = bx1 + base * math.sin(az), by1 + base * math.cos(az)
        px, py = rng.uniform(-2500.0, 2500.0, 2)
        if math.hypot(px - bx1, py - by1) > CFG.D_max_m or math.hypot(px - bx2, py - by2) > CFG.D_max_m:
            continue
        # distance to the beacon line
        d = abs((bx2 - bx1) * (py - by1) - (by2 - by1) * (px - bx1)) / base
        band = next((k for k, (lo, hi, _) in enumerate(U4_BOUNDS) if lo <= d < hi), None)
        if band is None or counts[band] >= 15:
            continue
        z0 = rng.uniform(0.0, 200.0)
        beacons = [("B1", bx1, by1, 100.0), ("B2", bx2, by2, 100.0)]
        res = initiation.launch(_noise_free_ranges((px, py), z0, beacons), z0, CFG)
        assert res.ok and len(res.candidates) == 2
        assert res.cluster_sizes == [6, 6]
        mx, my = _reflect(px, py, geo.baseline_azimuth(bx1, by1, bx2, by2), bx1, by1)
        pts = [(float(c.X0[0]), float(c.X0[1])) for c in res.candidates]
        e_true = min(math.dist(q, (px, py)) for q in pts)
        e_mirror = min(math.dist(q, (mx, my)) for q in pts)
        tol = U4_BOUNDS[band][2]
        assert e_true < tol and e_mirror < tol, (d, e_true, e_mirror)
        counts[band] += 1
        checked += 1
    assert checked == 15 * len(U4_BOUNDS)


# ---- U5 -----------------------------------------------------------------------------------------------------------
def test_u5_launch_covariances_are_mirror_images_with_unobservable_dc() -> None:
    rng = np.random.default_rng(5)
    for _ in range(20):
        alpha = rng.uniform(-math.pi, math.pi)
        b2 = (1500.0 * math.sin(alpha), 1500.0 * math.cos(alpha))
        beacons = [("B1", 0.0, 0.0, 100.0), ("B2", b2[0], b2[1], 120.0)]
        along, across = rng.uniform(200.0, 1300.0), rng.uniform(100.0, 900.0) * rng.choice([-1.0, 1.0])
        p = (along * math.sin(alpha) + across * math.cos(alpha), along * math.cos(alpha) - across * math.sin(alpha))
        lr = _noise_free_ranges(p, 30.0, beacons)
        noisy = [initiation.LaunchRange(r.beacon_id, r.bx, r.by, r.bz, r.y + rng.normal(0.0, 11.0), r.T_s) for r in lr]
        res = initiation.launch(noisy, 30.0, CFG)
        assert res.ok and len(res.candidates) == 2
        c1, c2 = res.candidates
        # reflection across the beacon line acts on (x, y) as I - 2 n n^T, n the unit normal of the line
        n = np.array([math.cos(alpha), -math.sin(alpha)])
        F = np.eye(3)
        F[:2, :2] -= 2.0 * np.outer(n, n)
        P1, P2 = c1.P0[:3, :3], c2.P0[:3, :3]
        assert np.allclose(P1, F @ P2 @ F.T, rtol=1e-6, atol=1e-6 * np.abs(P1).max())
        for c in (c1, c2):
            assert abs(c.P0[2, 2] - CFG.sigma_dc_mps**2) < 1e-9 * CFG.sigma_dc_mps**2
            assert abs(c.X0[2]) < 1e-9
            # the position errors are correlated with dc (the paper's remark): non-zero cross-covariance block
            corr = [c.P0[k, 2] / math.sqrt(c.P0[k, k] * c.P0[2, 2]) for k in (0, 1)]
            assert math.hypot(*corr) > 1e-2
            assert c.P0[3, 3] == pytest.approx(CFG.sigma_dK_rad**2)
            assert c.P0[4, 4] == pytest.approx(CFG.sigma_dU_mps**2)


# ---- U6 -----------------------------------------------------------------------------------------------------------
def test_u6_inconsistent_launch_ranges_do_not_crash_and_are_postponed() -> None:
    beacons = [("B1", 0.0, 0.0, 100.0), ("B2", 0.0, 1500.0, 100.0)]
    far_apart = [initiation.LaunchRange(b, x, y, z, 300.0, 0.2) for b, x, y, z in beacons]  # 300 + 300 < 1500
    res = initiation.launch(far_apart, 30.0, CFG)
    assert not res.ok and res.reason == "launch_inconsistent"
    nested = [
        initiation.LaunchRange("B1", 0.0, 0.0, 100.0, 3000.0, 2.0),
        initiation.LaunchRange("B2", 0.0, 1500.0, 100.0, 200.0, 0.13),
    ]
    assert not initiation.launch(nested, 30.0, CFG).ok


# ---- U7 -----------------------------------------------------------------------------------------------------------
def test_u7_forward_then_backward_returns_to_the_start() -> None:
    rng = np.random.default_rng(7)
    dr = [DrInterval(1.0, *rng.uniform(-5.0, 5.0, 2), *rng.uniform(-0.3, 0.3, 2)) for _ in range(60)]
    X0 = np.array([123.0, -456.0, 1.5, math.radians(4.0), 0.2, -0.1])
    # dK and dU held fixed: correlation times so long that a = 1 exactly in float64
    frozen = MotionModel(LblNavConfig(tau_dK_s=1e300, tau_dU_s=1e300))
    X = X0.copy()
    for d in dr:
        Phi, b, _ = frozen.forward(d)
        X = Phi @ X + b
    z = X[[0, 1, 3, 4, 5]]
    for d in reversed(dr):
        Phib, bb, _ = frozen.backward(d)
        z = Phib @ z + bb
    assert np.max(np.abs(z - X0[[0, 1, 3, 4, 5]])) < 1e-9
    # with the default Markov steps the positions still step back exactly when fed dK_{s+1}, dU_{s+1}
    default = MotionModel(CFG)
    hist = [X0.copy()]
    for d in dr:
        Phi, b, _ = default.forward(d)
        hist.append(Phi @ hist[-1] + b)
    for k in range(len(dr), 0, -1):
        Phib, bb, _ = default.backward(dr[k - 1])
        z = Phib @ hist[k][[0, 1, 3, 4, 5]] + bb
        assert np.max(np.abs(z[:2] - hist[k - 1][:2])) < 1e-9


# ---- U8, U12 (core level on the S1 replica) -----------------------------------------------------------------------
def _s1_sim(seed: int, t_end: float = 40.0):
    spec = s1_spec()
    from dataclasses import replace

    return simulate(replace(spec, t_end_s=t_end), np.random.default_rng(seed), seed)


def test_u8_ratio_is_one_at_launch() -> None:
    sim = _s1_sim(3, t_end=2.0)
    core = LblNavCore(LblNavConfig(preset="paper"))  # rule (6) on the EKF ratio (the honest preset decides here)
    launch_fix = None
    for m in sim.messages:
        for o in core.step(m):
            if getattr(o, "status", None) == "LAUNCH":
                launch_fix = o
                assert core.bank is not None
                assert core.bank.log_ratio() == 0.0
    assert launch_fix is not None
    assert launch_fix.log10_ratio == 0.0
    assert [h.probability for h in launch_fix.hypotheses] == [0.5, 0.5]
    assert not launch_fix.valid and launch_fix.estimate is None


def test_u12_both_filters_process_identical_measurements() -> None:
    sim = _s1_sim(11, t_end=40.0)
    core = LblNavCore(LblNavConfig(ratio_threshold=1e30, preset="paper"))  # never decide: keep both alive
    checked = 0
    for m in sim.messages:
        core.step(m)
        if core.bank is not None and len(core.bank.hyps) == 2:
            h1, h2 = core.bank.hyps
            assert h1.n_rows == h2.n_rows
            assert list(h1.row_log) == list(h2.row_log)
            assert h1.crc == h2.crc
            checked += 1
    assert core.bank is not None and core.bank.hyps[0].n_rows > 300  # buffered and current rows were processed
    assert checked > 50


# ---- U9 -----------------------------------------------------------------------------------------------------------
def test_u9_mirrored_scenario_flips_the_label_and_the_log_ratio() -> None:
    from dataclasses import replace

    from schemas import Current, Heading, SpeedLog

    alpha = math.radians(30.0)
    b2 = (1500.0 * math.sin(alpha), 1500.0 * math.cos(alpha))
    rot = lambda x, y: (x * math.cos(-alpha) - y * math.sin(-alpha), x * math.sin(-alpha) + y * math.cos(-alpha))  # noqa: E731
    spec = replace(
        s1_spec(),
        beacons=(SimBeacon("B1", 0.0, 0.0, 100.0), SimBeacon("B2", b2[0], b2[1], 100.0)),
        heading_knots=tuple((t, h + 30.0) for t, h in s1_spec().heading_knots),
        launch_xy_m=rot(450.0, 606.97),
        v_starboard_mps=0.3,
        known_current_ne_mps=(0.1, -0.2),
        t_start_s=-150.0,
        t_end_s=30.0,
    )
    sim = simulate(spec, np.random.default_rng(9), 9)
    d = np.array([math.sin(alpha), math.cos(alpha)])  # (E, N) direction of the beacon line

    def mirror(m):  # type: ignore[no-untyped-def]
        if isinstance(m, Heading):
            return m.model_copy(update={"heading_rad": math.remainder(2.0 * alpha - m.heading_rad, 2.0 * math.pi)})
        if isinstance(m, SpeedLog):
            return m.model_copy(update={"v_starboard_mps": -m.v_starboard_mps})
        if isinstance(m, Current):
            v = np.array([m.u_east_mps, m.u_north_mps])
            r = 2.0 * (v @ d) * d - v
            return m.model_copy(update={"u_east_mps": float(r[0]), "u_north_mps": float(r[1])})
        return m  # ranges, depth and the beacon table are unchanged by the reflection

    cfg = LblNavConfig(ratio_threshold=1e30, preset="paper")  # the EKF ratio, never decided
    ratios = []
    for msgs in (sim.messages, [mirror(m) for m in sim.messages]):
        core = LblNavCore(cfg)
        lr = []
        for m in msgs:
            lr += [o.log10_ratio for o in core.step(m) if isinstance(o, LblFix) and o.log10_ratio is not None]
        ratios.append(np.array(lr))
    a, b = ratios
    assert a.size == b.size and a.size > 10
    assert np.max(np.abs(a + b)) < 1e-6 * max(1.0, float(np.max(np.abs(a))))
    assert abs(a[-1]) > 0.5  # the ratio has moved away from 1, so the label flip is meaningful
    # the label of the better hypothesis flips
    assert np.sign(a[-1]) == -np.sign(b[-1])


# ---- U10 ----------------------------------------------------------------------------------------------------------
def _forward_reference(cfg: LblNavConfig, epochs: list[tuple[DrInterval | None, list[LinearRow]]]) -> tuple:
    """Plain forward Kalman filter from t_{-N} (diffuse position 1e10 m^2, stationary priors), written here from
    the digest's equations (1)-(2) independently of services.lbl_nav.models."""
    X = np.zeros(6)
    P = np.diag([1e10, 1e10, cfg.sigma_dc_mps**2, cfg.sigma_dK_rad**2, cfg.sigma_dU_mps**2, cfg.sigma_dU_mps**2])
    aK = math.exp(-cfg.dt_s / cfg.tau_dK_s)
    aU = math.exp(-cfg.dt_s / cfg.tau_dU_s)
    for dr, rows in epochs:
        if dr is not None:
            dt = dr.dt_s
            # state after the Markov step, then the position step using dK_i, dU_i (Eq. 2)
            A = np.diag([1.0, 1.0, 1.0, aK, aU, aU])
            B = np.eye(6)
            B[0, 3], B[0, 5] = dr.vn_dt_m, dt
            B[1, 3], B[1, 4] = -dr.ve_dt_m, dt
            F = B @ A
            u = np.array([dr.ve_dt_m + dr.ue_dt_m, dr.vn_dt_m + dr.un_dt_m, 0, 0, 0, 0])
            G = np.diag(
                [
                    0,
                    0,
                    0,
                    cfg.sigma_dK_rad**2 * (1 - aK**2),
                    cfg.sigma_dU_mps**2 * (1 - aU**2),
                    cfg.sigma_dU_mps**2 * (1 - aU**2),
                ]
            )
            Qn = B @ G @ B.T + np.diag([cfg.sigma_dV_mps**2 * dt] * 2 + [0.0] * 4)
            X = F @ X + u
            P = F @ P @ F.T + Qn
        if rows:
            H = np.array([[r.hx, r.hy, r.hdc, 0, 0, 0] for r in rows])
            z = np.array([r.value - r.h0 for r in rows])
            R = cfg.sigma_delta_m**2 * np.ones((len(rows), len(rows))) + cfg.sigma_v_m**2 * np.eye(len(rows))
            S = H @ P @ H.T + R
            K = P @ H.T @ np.linalg.inv(S)
            X = X + K @ (z - H @ X)
            P = (np.eye(6) - K @ H) @ P
            P = 0.5 * (P + P.T)
    return X, P


def linear_case(dN0: int, dN: int) -> dict:  # type: ignore[type-arg]
    """A buffered-data case with linear 'range' rows (gradients of ranges at fixed points) consistent with the DR."""
    # gate disabled: the comparison is of the filtering scheme alone
    cfg = LblNavConfig(dN0=dN0, dN=dN, heading_linearisation="zero", gate_prob=1.0 - 1e-15)
    rng = np.random.default_rng(10)
    N, n_cur = 37, 45
    beacons = [(0.0, 0.0), (0.0, 1500.0)]
    drs = {k: DrInterval(1.0, *rng.uniform(-5.0, 5.0, 2), *rng.uniform(-0.2, 0.2, 2)) for k in range(-N + 1, n_cur + 1)}
    # a true track consistent with the DR (dK = dU = 0, dc = 0) through (450, 600) at t_0
    track = {0: np.array([450.0, 600.0])}
    for k in range(1, n_cur + 1):
        track[k] = track[k - 1] + [drs[k].ve_dt_m + drs[k].ue_dt_m, drs[k].vn_dt_m + drs[k].un_dt_m]
    for k in range(0, -N, -1):
        track[k - 1] = track[k] - [drs[k].ve_dt_m + drs[k].ue_dt_m, drs[k].vn_dt_m + drs[k].un_dt_m]

    def row(block: str, k: int, j: int) -> LinearRow:
        bx, by = beacons[j]
        px, py = 450.0 + 3.0 * k, 600.0 + 4.0 * k
        D = math.hypot(bx - px, by - py)
        hx, hy = -(bx - px) / D, -(by - py) / D
        h0 = D - hx * px - hy * py
        value = h0 + hx * track[k][0] + hy * track[k][1] + rng.normal(0.0, 11.0)
        return LinearRow(block, k, k, f"B{j + 1}", float(value), h0, hx, hy, D / 1500.0)

    buffered = {k: [row("s", k, 0)] for k in range(-N, 0) if k % 7 != 3}  # some epochs without a range
    current = {k: [row("i", k, j) for j in range(2) if (k + j) % 3 != 2] for k in range(1, n_cur + 1)}
    launch_rows = [row("i", 0, 0), row("i", 0, 1)]
    chi, P_chi, _, _ = initiation.chi_estimate(400.0, 650.0, launch_rows, cfg)
    X0, P0 = initiation.initial_state(chi, P_chi, cfg)
    buf = [BufferedEpoch(k, k, drs[k] if k > -N else DrInterval(1.0, 0, 0), buffered.get(k, [])) for k in range(-N, 0)]
    return {
        "cfg": cfg,
        "N": N,
        "drs": drs,
        "buffered": buffered,
        "current": current,
        "launch_rows": launch_rows,
        "X0": X0,
        "P0": P0,
        "buf": buf,
    }


def forward_reference_after(case: dict, i_end: int) -> tuple:  # type: ignore[type-arg]
    """The forward reference filter over Y_{-N} ... Y_{i_end} (rows re-addressed to the 6-state block)."""

    def as_ref(rows: list[LinearRow]) -> list[LinearRow]:
        return [LinearRow("i", r.group, r.stamp_ns, r.key, r.value, r.h0, r.hx, r.hy, r.hdc) for r in rows]

    N, drs, buffered = case["N"], case["drs"], case["buffered"]
    epochs = [(None, as_ref(buffered.get(-N, [])))]
    epochs += [(drs[k], as_ref(buffered.get(k, []))) for k in range(-N + 1, 0)]
    epochs += [(drs[0], as_ref(case["launch_rows"]))]
    epochs += [(drs[k], as_ref(case["current"][k])) for k in range(1, i_end + 1)]
    return _forward_reference(case["cfg"], epochs)


@pytest.mark.parametrize("dN0,dN", [(0, 10), (3, 5), (40, 10), (0, 1)])
def test_u10_augmented_backward_processing_equals_a_forward_filter_in_the_linear_case(dN0: int, dN: int) -> None:
    case = linear_case(dN0, dN)
    cfg = case["cfg"]
    bank = HypothesisBank(
        cfg, MotionModel(cfg), [HypothesisFilter(1, case["X0"], case["P0"])], case["buf"], case["drs"][0]
    )
    bank.launch_steps()
    i = 0
    while bank.catching_up or i == 0:
        i += 1
        bank.epoch_step(case["drs"][i], case["current"][i])
    Xa, Pa = bank.hyps[0].current()
    Xr, Pr = forward_reference_after(case, i)
    sig = np.sqrt(np.diag(Pr))
    assert np.all(np.abs(Xa - Xr) <= 1e-3 * sig), (Xa - Xr) / sig
    assert np.allclose(Pa, Pr, rtol=1e-3, atol=1e-6 * np.abs(Pr).max())


# ---- U11 ----------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "N,dN0,dN,last_i", [(360, 0, 10, 36), (97, 0, 10, 10), (360, 360, 10, 0), (97, 97, 10, 0), (95, 5, 10, 9)]
)
def test_u11_schedule_bookkeeping(N: int, dN0: int, dN: int, last_i: int) -> None:
    cfg = LblNavConfig(dN0=dN0, dN=dN)
    dr = DrInterval(1.0, 0.0, 5.0)
    buf = [BufferedEpoch(k, k, dr, []) for k in range(-N, 0)]
    X0 = np.array([450.0, 600.0, 0.0, 0.0, 0.0, 0.0])
    P0 = np.diag([100.0, 100.0, 9.0, 0.0076, 0.0625, 0.0625])
    bank = HypothesisBank(cfg, MotionModel(cfg), [HypothesisFilter(1, X0, P0)], buf, dr)
    assert bank.augmented
    bank.launch_steps()
    done_at = 0 if not bank.catching_up else None
    assert bank.augmented == bank.catching_up
    i = 0
    while done_at is None:
        i += 1
        assert bank.augmented
        bank.epoch_step(dr, [])
        if not bank.catching_up:
            done_at = i
            assert not bank.augmented  # augmentation dropped at the same epoch
            assert bank.hyps[0].X.size == 6
    assert done_at == last_i
    assert bank.processed == N


def test_u11_core_reports_catching_up_until_t0_plus_36_s() -> None:
    sim = _s1_sim(5, t_end=40.0)
    core = LblNavCore(LblNavConfig())
    fixes = []
    for m in sim.messages:
        fixes += [o for o in core.step(m) if getattr(o, "launch_stamp_ns", None) is not None]
    fixes += [o for o in core.flush() if getattr(o, "launch_stamp_ns", None) is not None]
    t0 = fixes[0].launch_stamp_ns
    by_t = {round((f.header.stamp_ns - t0) / 1e9): f for f in fixes if hasattr(f, "catching_up")}
    assert by_t[0].buffered_epochs == 360
    assert all(by_t[t].catching_up for t in range(0, 36))
    assert not by_t[36].catching_up and by_t[36].saved_progress == 1.0
    assert by_t[35].processed_buffered == 350


def test_spec_helpers_are_consistent() -> None:
    spec = ScenarioSpec("x", (SimBeacon("B1", 0, 0, 100),), ((0.0, 10.0),), (0.0, 0.0), -5.0, 5.0)
    assert spec.heading_deg(np.array([0.0]))[0] == 10.0
