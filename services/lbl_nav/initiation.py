"""Launch of the solution at the first epoch with two or more beacons (digest 000, sections 2.1 and 2.2).

Two beacons: rotation (3), pseudo-measurement (4)/(U1), grid (U2), Gauss-Newton from every node (Step 4),
largest-gap split (U3), cluster means (U4), rotation back and the 3-state estimate (U5) per hypothesis,
then the 6-state X_0, P_0 (Step 7). Three or more: collinear -> as two beacons on the common line;
otherwise a unique least-squares solution, kept alone unless its error ellipse is too large ([R/IMPL]).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from shared.filters.covariance import symmetrize

from . import geometry as geo
from .config import LblNavConfig
from .models import F64, RangeRow, Row


@dataclass(frozen=True)
class LaunchRange:
    """A range of the launch epoch: beacon position (m, depth + down), slant range y (m), travel time T (s)."""

    beacon_id: str
    bx: float
    by: float
    bz: float
    y: float
    T_s: float


@dataclass
class Candidate:
    """One launch hypothesis: X_0 (6), P_0 (6x6) and the seeds of A and ln B."""

    X0: F64
    P0: F64
    A0: float = 0.0
    lnB0: float = 0.0  # noqa: N815


@dataclass
class LaunchResult:
    ok: bool
    reason: str = ""
    detail: str = ""
    candidates: list[Candidate] = field(default_factory=list)
    grid_nodes: int = 0
    cluster_sizes: list[int] = field(default_factory=list)
    centres: list[tuple[float, float]] = field(default_factory=list)
    alpha_rad: float = 0.0
    xb_m: float = 0.0
    unique: bool = False


def lsq_weight(ranges: Sequence[LaunchRange], cfg: LblNavConfig) -> F64:
    """[R] Step 4 weight: inverse of sigma_delta^2 1 1^T + sigma_v^2 I + sigma_dc^2 T T^T."""
    n = len(ranges)
    T = np.array([r.T_s for r in ranges])
    R = cfg.sigma_delta_m**2 * np.ones((n, n)) + cfg.sigma_v_m**2 * np.eye(n) + cfg.sigma_dc_mps**2 * np.outer(T, T)
    return np.asarray(np.linalg.inv(R), dtype=np.float64)


def gauss_newton(
    x0: float, y0: float, ranges: Sequence[LaunchRange], z0: float, W: F64, iters: int
) -> tuple[float, float, bool, float]:
    """Iterative weighted LSQ for the horizontal position, no prior (Step 4). Returns x, y, ok, r^T W r."""
    bx = np.array([r.bx for r in ranges])
    by = np.array([r.by for r in ranges])
    dz2 = (np.array([r.bz for r in ranges]) - z0) ** 2
    Y = np.array([r.y for r in ranges])
    x, y = x0, y0
    for _ in range(iters):
        ex, ey = x - bx, y - by
        D = np.sqrt(ex * ex + ey * ey + dz2)
        H = np.column_stack([ex / D, ey / D])
        r = Y - D
        N = H.T @ W @ H
        det = N[0, 0] * N[1, 1] - N[0, 1] * N[1, 0]
        if not np.isfinite(det) or det <= 1e-12 * (N[0, 0] + N[1, 1]) ** 2:
            return x, y, False, math.inf
        step = np.linalg.solve(N, H.T @ W @ r)
        x, y = x + float(step[0]), y + float(step[1])
        if not (math.isfinite(x) and math.isfinite(y)):
            return x, y, False, math.inf
    D = np.sqrt((x - bx) ** 2 + (y - by) ** 2 + dz2)
    r = Y - D
    return x, y, True, float(r @ W @ r)


def chi_estimate(x0: float, y0: float, rows: Sequence[Row], cfg: LblNavConfig) -> tuple[F64, F64, float, float]:
    """(U5): chi = (x, y, dc) linearised at (x0, y0, 0); no prior on x, y; 1/sigma_dc^2 on dc.

    Returns chi_hat, P_chi, the weighted residual (A seed) and -ln det P_chi (ln B seed).
    """
    n = len(rows)
    H = np.zeros((n, 3))
    r = np.empty(n)
    for j, row in enumerate(rows):
        h, hx, hy, hdc = row.predict(x0, y0, 0.0)
        H[j] = (hx, hy, hdc)
        r[j] = row.value - h
    R = cfg.sigma_delta_m**2 * np.ones((n, n)) + cfg.sigma_v_m**2 * np.eye(n)
    Ri = np.linalg.inv(R)
    info = H.T @ Ri @ H
    info[2, 2] += 1.0 / cfg.sigma_dc_mps**2
    P = np.linalg.inv(info)
    P = symmetrize(P)
    chi = np.array([x0, y0, 0.0]) + P @ H.T @ Ri @ r
    # fit of Y_0 at chi_hat (linearised) and the prior term on dc
    res = r - H @ (chi - np.array([x0, y0, 0.0]))
    A0 = float(res @ Ri @ res) + float(chi[2] ** 2 / cfg.sigma_dc_mps**2)
    lnB0 = -float(np.linalg.slogdet(P)[1])
    return chi, P, A0, lnB0


def initial_state(chi: F64, P_chi: F64, cfg: LblNavConfig) -> tuple[F64, F64]:
    """Step 7: X_0 = (chi, 0, 0, 0), P_0 = blockdiag(P_chi, diag(sigma_dK^2, sigma_dU^2, sigma_dU^2))."""
    X0 = np.zeros(6)
    X0[:3] = chi
    P0 = np.zeros((6, 6))
    P0[:3, :3] = P_chi
    P0[3, 3] = cfg.sigma_dK_rad**2
    P0[4, 4] = P0[5, 5] = cfg.sigma_dU_mps**2
    return X0, P0


def _rows(ranges: Sequence[LaunchRange], z0: float, k: int, stamp_ns: int) -> list[Row]:
    return [RangeRow("i", k, stamp_ns, r.beacon_id, r.y, r.bx, r.by, r.bz, z0, r.T_s) for r in ranges]


def _grid_solutions(
    ranges: Sequence[LaunchRange], z0: float, alpha: float, xb: float, ybar0: float, cfg: LblNavConfig
) -> tuple[int, F64, F64]:
    """Steps 3-4: Gauss-Newton from each grid node; returns L and the rotated (xbar, ybar) of the good nodes."""
    L = cfg.grid_nodes()
    half = cfg.grid_half_width_m if cfg.grid_half_width_m is not None else cfg.D_max_m
    nodes = geo.grid_xbar(xb, half, L)
    W = lsq_weight(ranges, cfg)
    thr = float(chi2.ppf(cfg.gn_residual_prob, max(len(ranges) - 2, 1)))
    xs, ys = [], []
    for xn in nodes:
        x0, y0 = geo.unrotate(xn, ybar0, alpha)
        x, y, ok, res = gauss_newton(float(x0), float(y0), ranges, z0, W, cfg.gn_iter)
        if ok and res <= thr:
            xr, yr = geo.rotate(x, y, alpha)
            xs.append(float(xr))
            ys.append(float(yr))
    return L, np.array(xs), np.array(ys)


def _split(xbar: F64, ybar: F64, cfg: LblNavConfig) -> list[tuple[int, float, float]]:
    """(U3)-(U4): sort by xbar, cut at the largest gap, plain means. One cluster if the gap is tiny."""
    order = np.argsort(xbar, kind="stable")
    xs, ys = xbar[order], ybar[order]
    if xs.size == 1:
        return [(1, float(xs[0]), float(ys[0]))]
    gaps = np.diff(xs)
    LI = int(np.argmax(gaps)) + 1
    if gaps[LI - 1] < cfg.cluster_min_gap_m:
        return [(xs.size, float(xs.mean()), float(ys.mean()))]
    return [
        (LI, float(xs[:LI].mean()), float(ys[:LI].mean())),
        (xs.size - LI, float(xs[LI:].mean()), float(ys[LI:].mean())),
    ]


def _two_hypotheses(
    ranges: Sequence[LaunchRange],
    z0: float,
    alpha: float,
    xb: float,
    ybar0: float,
    cfg: LblNavConfig,
    k: int,
    stamp_ns: int,
    evidence: bool,
) -> LaunchResult:
    L, xbar, ybar = _grid_solutions(ranges, z0, alpha, xb, ybar0, cfg)
    if xbar.size < 2:
        return LaunchResult(False, "launch_degenerate", f"{xbar.size} of {L} grid nodes converged", grid_nodes=L)
    clusters = _split(xbar, ybar, cfg)
    rows = _rows(ranges, z0, k, stamp_ns)
    res = LaunchResult(True, grid_nodes=L, alpha_rad=alpha, xb_m=xb, unique=len(clusters) == 1)
    for size, xc, yc in clusters:
        x, y = geo.unrotate(xc, yc, alpha)
        chi, P_chi, A0, lnB0 = chi_estimate(float(x), float(y), rows, cfg)
        X0, P0 = initial_state(chi, P_chi, cfg)
        if not evidence:
            A0, lnB0 = 0.0, 0.0
        res.candidates.append(Candidate(X0, P0, A0, lnB0))
        res.cluster_sizes.append(size)
        res.centres.append((float(x), float(y)))
    return res


def launch(ranges: Sequence[LaunchRange], z0: float, cfg: LblNavConfig, k: int = 0, stamp_ns: int = 0) -> LaunchResult:
    """Form one or two hypotheses from the ranges of the launch epoch (n_0 >= 2) at vehicle depth z0 (m)."""
    n = len(ranges)
    if n < 2:
        return LaunchResult(False, "launch_degenerate", "fewer than two ranges")
    sig = cfg.gate_sigma_k * cfg.sigma_range_m
    hr = [math.sqrt(max(r.y**2 - (r.bz - z0) ** 2, 0.0)) for r in ranges]
    # [IMPL] launch sanity: every pair of horizontal ranges consistent with its baseline
    for a in range(n):
        for b in range(a + 1, n):
            base = math.hypot(ranges[b].bx - ranges[a].bx, ranges[b].by - ranges[a].by)
            if abs(hr[a] - hr[b]) > base + sig or hr[a] + hr[b] < base - sig:
                return LaunchResult(
                    False,
                    "launch_inconsistent",
                    f"{ranges[a].beacon_id}/{ranges[b].beacon_id}: horizontal ranges {hr[a]:.1f}, {hr[b]:.1f} m, "
                    f"baseline {base:.1f} m",
                )
    bx = np.array([r.bx for r in ranges])
    by = np.array([r.by for r in ranges])
    if n == 2:
        alpha = geo.baseline_azimuth(bx[0], by[0], bx[1], by[1])
        xr, yr = geo.rotate(bx, by, alpha)
        if yr[1] - yr[0] <= 1e-6:
            return LaunchResult(False, "launch_degenerate", "the two beacons coincide horizontally")
        ybar0 = geo.ybar0_two(
            ranges[0].y, ranges[1].y, float(yr[0]), float(yr[1]), ranges[0].bz - z0, ranges[1].bz - z0
        )
        return _two_hypotheses(ranges, z0, alpha, float(xr[0]), ybar0, cfg, k, stamp_ns, evidence=False)

    alpha, spread = geo.principal_axis(bx, by)
    xr, yr = geo.rotate(bx, by, alpha)
    dz = np.array([r.bz - z0 for r in ranges])
    Y = np.array([r.y for r in ranges])
    if np.ptp(yr) <= 1e-6:
        return LaunchResult(False, "launch_degenerate", "all beacons coincide horizontally")
    if spread >= cfg.collinear_tol_m:
        # [R/IMPL] unique solution: linear LSQ on differences of squared horizontal ranges, then Gauss-Newton
        r2 = Y**2 - dz**2
        A = 2.0 * np.column_stack([bx[1:] - bx[0], by[1:] - by[0]])
        rhs = r2[0] - r2[1:] - (bx[0] ** 2 + by[0] ** 2) + (bx[1:] ** 2 + by[1:] ** 2)
        p, *_ = np.linalg.lstsq(A, rhs, rcond=None)
        W = lsq_weight(ranges, cfg)
        x, y, ok, _ = gauss_newton(float(p[0]), float(p[1]), ranges, z0, W, cfg.gn_iter)
        if ok:
            rows = _rows(ranges, z0, k, stamp_ns)
            chi, P_chi, _, _ = chi_estimate(x, y, rows, cfg)
            major = math.sqrt(max(float(np.linalg.eigvalsh(P_chi[:2, :2])[-1]), 0.0))
            # [IMPL] the mirror image across the beacons' best-fit line must not fit the ranges as well
            mx, my = geo.reflect_point(x, y, alpha, float(np.mean(xr)))
            xm, ym, okm, res_m = gauss_newton(mx, my, ranges, z0, W, cfg.gn_iter)
            thr = float(chi2.ppf(cfg.gn_residual_prob, max(n - 2, 1)))
            mirror_fits = okm and res_m <= thr and math.hypot(xm - x, ym - y) > cfg.r_merge_m
            if major <= cfg.ellipse_axis_max_m and not mirror_fits:
                X0, P0 = initial_state(chi, P_chi, cfg)
                return LaunchResult(
                    True,
                    candidates=[Candidate(X0, P0)],
                    cluster_sizes=[1],
                    centres=[(x, y)],
                    unique=True,
                    alpha_rad=alpha,
                )
    # collinear or unfavourable: two hypotheses on the best-fit line of the beacons
    ybar0 = geo.ybar0_multi(Y, yr, dz)
    return _two_hypotheses(
        ranges, z0, alpha, float(np.mean(xr)), ybar0, cfg, k, stamp_ns, evidence=cfg.launch_evidence_multi
    )
