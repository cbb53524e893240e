"""The vectorised hot paths of the PCL tracker core decide exactly as their plain references.

* :func:`association.gate_pairs` (sorted-r_b window + one-component bounds) = :func:`gate_matrix` ≤ γ₄;
* :func:`association.assign_pairs` (per connected component) = :func:`assign_gnn` / :func:`assign_nn` on the
  dense matrices;
* :func:`initiation.ring_gate_pairs` (k-d tree + exact bound) = :func:`ring_ellipse_test` on every pair;
* :func:`plots.normalise_plots` (arrays) = the §5.6 rules applied plot by plot (a scalar reference below).
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest
from scipy.stats import chi2

from schemas.radar import BistaticPlot
from services.pcl_tracker.association import assign_gnn, assign_nn, assign_pairs, gate_matrix, gate_pairs
from services.pcl_tracker.config import PclTrackerConfig
from services.pcl_tracker.filter import bistatic_image
from services.pcl_tracker.initiation import ring_ellipse_test, ring_gate_pairs
from services.pcl_tracker.models import plot_covariance
from services.pcl_tracker.plots import normalise_plots
from shared.filters.angles import wrap_pi

TX = np.array([8000.0, 0.0, 300.0])
G4 = float(chi2.ppf(0.99, 4))
G3 = float(chi2.ppf(0.99, 3))


def scene(rng: np.random.Generator, n_tracks: int, n_clutter: int) -> tuple[np.ndarray, ...]:
    """Predicted bistatic measurements of random tracks, their plots (some straddling ±180°) and clutter."""
    x = np.column_stack(
        [rng.uniform(-3e4, 3e4, (n_tracks, 2)), rng.uniform(300, 8000, n_tracks), rng.normal(0, 150, (n_tracks, 3))]
    )
    x[: n_tracks // 4, 1] = -np.abs(x[: n_tracks // 4, 1]) - 1000.0  # south: azimuth near ±180°
    x[: n_tracks // 4, 0] = rng.normal(0, 30, n_tracks // 4)
    A = rng.normal(size=(n_tracks, 6, 6)) * np.array([300, 300, 300, 20, 20, 20])[:, None]
    P = A @ np.swapaxes(A, 1, 2) / 6 + np.eye(6)
    pred = bistatic_image(x, P, TX)
    sig = np.column_stack(
        [
            rng.uniform(50, 400, n_tracks + n_clutter),
            np.radians(rng.uniform(0.1, 1.0, (n_tracks + n_clutter, 2))),
            rng.uniform(1, 10, n_tracks + n_clutter),
        ]
    )
    z_true = pred.mean + rng.standard_normal((n_tracks, 4)) * np.sqrt(np.diagonal(pred.cov, axis1=1, axis2=2)) * 0.7
    lo, hi = np.array([0.0, -math.pi, 0.0, -450.0]), np.array([60_000.0, math.pi, 0.5, 450.0])
    clutter = lo + rng.random((n_clutter, 4)) * (hi - lo)
    z = np.vstack([z_true, clutter])
    z[:, 1] = wrap_pi(z[:, 1])
    return pred.mean, pred.cov, z, plot_covariance(sig)


@pytest.mark.parametrize("seed", range(6))
def test_sparse_gating_equals_the_dense_gate(seed: int) -> None:
    rng = np.random.default_rng(seed)
    zp, Rp, z, Rz = scene(rng, 60, 400)
    z[60:90] = z[:30] + rng.normal(0, 0.5, (30, 4)) * np.sqrt(np.diagonal(Rz[:30], axis1=1, axis2=2))  # twins
    z[:, 1] = wrap_pi(z[:, 1])
    d2, logdet = gate_matrix(zp, Rp, z, Rz)
    gp = gate_pairs(zp, Rp, z, Rz, G4)
    ti, pj = np.nonzero(d2 <= G4)
    assert ti.size > 70  # the scene has ambiguity (several plots in some gates)
    np.testing.assert_array_equal(gp.track, ti)
    np.testing.assert_array_equal(gp.plot, pj)
    np.testing.assert_allclose(gp.d2, d2[ti, pj], rtol=1e-12)
    np.testing.assert_allclose(gp.logdet, logdet[ti, pj], rtol=1e-12)
    near_pm_pi = np.abs(zp[:, 1]) > math.radians(170)
    assert near_pm_pi.any() and np.isin(np.flatnonzero(near_pm_pi), gp.track).any()  # the wrap is exercised


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("method", ["gnn", "nn"])
def test_component_assignment_equals_the_dense_assignment(seed: int, method: str) -> None:
    rng = np.random.default_rng(100 + seed)
    zp, Rp, z, Rz = scene(rng, 80, 300)
    z[80:120] = z[:40] + rng.normal(0, 0.3, (40, 4)) * np.sqrt(np.diagonal(Rz[:40], axis1=1, axis2=2))  # contention
    z[:, 1] = wrap_pi(z[:, 1])
    # crossing targets: tracks 60-79 predicted next to tracks 0-19, so they compete for the same plots
    zp[60:80] = zp[:20] + rng.normal(0, 0.4, (20, 4)) * np.sqrt(np.diagonal(Rp[:20], axis1=1, axis2=2))
    Rp[60:80] = Rp[:20]
    d2, logdet = gate_matrix(zp, Rp, z, Rz)
    gp = gate_pairs(zp, Rp, z, Rz, G4)
    rows_allowed = rng.random(80) < 0.7
    cols_free = rng.random(z.shape[0]) < 0.9
    dense_g = (d2 <= G4) & rows_allowed[:, None] & cols_free[None, :]
    for cost, cost_pairs in ((d2, gp.d2), (d2 + logdet, gp.d2 + gp.logdet)):
        ref = (assign_gnn if method == "gnn" else assign_nn)(cost, dense_g)
        got = assign_pairs(gp, cost_pairs, rows_allowed, cols_free, method)
        assert sorted(got) == sorted(ref)
        assert len(ref) > 30
    shared = np.bincount(gp.plot[rows_allowed[gp.track]])
    assert (shared > 1).sum() >= 5  # plots inside several allowed tracks' gates: real contention


@pytest.mark.parametrize("seed", range(4))
def test_pruned_ring_gate_equals_the_full_test(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    C, P = 300, 350
    zc1 = rng.uniform(-2e4, 2e4, (C, 3))
    zc2 = np.vstack([zc1[:150] + rng.normal(0, 600, (150, 3)), rng.uniform(-2e4, 2e4, (P - 150, 3))])
    A1 = rng.normal(size=(C, 3, 3)) * 150
    A2 = rng.normal(size=(P, 3, 3)) * 150
    Rc1 = A1 @ np.swapaxes(A1, 1, 2) + np.eye(3)
    Rc2 = A2 @ np.swapaxes(A2, 1, 2) + np.eye(3)
    tau = rng.choice([3.0, 6.0], C)
    full, _, _ = ring_ellipse_test(zc1[:, None], Rc1[:, None], zc2[None], Rc2[None], tau[:, None], 30.0, 400.0, G3)
    ci, pj = np.nonzero(full)
    got_ci, got_pj = ring_gate_pairs(zc1, Rc1, tau, zc2, Rc2, 30.0, 400.0, G3)
    assert ci.size > 100
    np.testing.assert_array_equal(got_ci, ci)
    np.testing.assert_array_equal(got_pj, pj)


# ------------------------------------------------------------------------------------------------ plots
def _finite(v: object) -> bool:
    return isinstance(v, int | float) and math.isfinite(v)


def scalar_reference(plots: list[BistaticPlot], cfg: PclTrackerConfig, L: float, wl: float | None) -> tuple:
    """Digest §5.6, one plot at a time, in the order of the rules (the pre-vectorisation implementation)."""
    geo, lim, md = cfg.geometry, cfg.limits, cfg.measurement_defaults
    rejected: Counter[str] = Counter()
    flagged: Counter[str] = Counter()
    rows = []
    seen: set[str] = set()
    for p in plots:
        if p.plot_id in seen:
            rejected["duplicate_plot_id"] += 1
            continue
        seen.add(p.plot_id)
        forms = [f for f in (p.bistatic_range_m, p.range_sum_m, p.delay_s) if f is not None]
        vforms = [f for f in (p.bistatic_velocity_mps, p.doppler_hz) if f is not None]
        if len(forms) != 1 or len(vforms) != 1:
            rejected["missing_quantity"] += 1
            continue
        if not all(_finite(v) for v in (*forms, *vforms, p.azimuth_deg, p.elevation_deg)):
            rejected["nan"] += 1
            continue
        if p.bistatic_range_m is not None:
            rb = float(p.bistatic_range_m)
        elif p.range_sum_m is not None:
            rb = float(p.range_sum_m) - L
        else:
            rb = geo.c_mps * float(p.delay_s)  # type: ignore[arg-type]
        if p.bistatic_velocity_mps is not None:
            vb = float(p.bistatic_velocity_mps)
        elif wl is None:
            rejected["no_wavelength"] += 1
            continue
        else:
            vb = geo.doppler_sign * wl * float(p.doppler_hz)  # type: ignore[arg-type]
        sig = []
        bad = False
        for g, s, native in zip(
            (p.sigma_rb_m, p.sigma_az_deg, p.sigma_el_deg, p.sigma_vb_mps),
            (1.0, math.pi / 180, math.pi / 180, 1.0),
            (md.sigma_rb_m, md.sigma_az_deg, md.sigma_el_deg, md.sigma_vb_mps),
            strict=True,
        ):
            if g is None:
                sig.append(native * s)
            elif not _finite(g) or g <= 0 or g > md.absurd_factor * native:
                bad = True
                sig.append(native * s)
            else:
                sig.append(float(g) * s)
        if bad:
            flagged["sigma_defaulted"] += 1
        if rb < 0:
            if rb >= -lim.near_baseline_sigmas * sig[0]:
                rb = 0.0
                flagged["near_baseline"] += 1
            else:
                rejected["rb_below_baseline"] += 1
                continue
        el = math.radians(float(p.elevation_deg))
        if (
            rb > lim.rb_max_m
            or abs(vb) > lim.vb_max_abs_mps
            or not (math.radians(lim.el_min_deg) <= el <= math.radians(lim.el_max_deg))
        ):
            rejected["out_of_range"] += 1
            continue
        az = math.pi - math.fmod(math.pi - math.radians(float(p.azimuth_deg)), 2 * math.pi)
        az = az + 2 * math.pi if az <= -math.pi else az - 2 * math.pi if az > math.pi else az
        if rb < lim.rb_min_convertible_m:
            flagged["low_rb"] += 1
        rows.append((p.plot_id, [rb, az, el, vb], sig, rb < lim.rb_min_convertible_m))
    rows.sort(key=lambda r: r[0])
    return [r[0] for r in rows], np.array([r[1] for r in rows]).reshape(-1, 4), rejected, flagged, rows


@pytest.mark.parametrize("seed", range(40))
def test_vectorised_plot_rules_equal_the_scalar_rules(seed: int) -> None:
    rng = np.random.default_rng(300 + seed)

    def val(kind: str) -> float | None:
        u = rng.random()
        if u < 0.05:
            return math.nan
        if u < 0.08:
            return math.inf * rng.choice([-1, 1])
        return {
            "rb": rng.choice([rng.uniform(-2000, 250_000), rng.uniform(-700, 700)]),
            "sig": rng.choice([rng.uniform(-1, 3000), 0.0, rng.uniform(0, 20)]),
            "el": rng.uniform(-95, 95),
            "az": rng.uniform(-1000, 1000),
            "vb": rng.uniform(-1200, 1200),
        }[kind]

    plots = []
    for _ in range(int(rng.integers(0, 60))):
        d: dict[str, object] = {
            "plot_id": f"p{rng.integers(0, 40):03d}",
            "azimuth_deg": val("az"),
            "elevation_deg": val("el"),
        }
        form = rng.choice(["bistatic_range_m", "range_sum_m", "delay_s", "none", "two"])
        if form == "two":
            d["bistatic_range_m"], d["range_sum_m"] = val("rb"), 9000.0
        elif form == "delay_s":
            d["delay_s"] = (val("rb") or 0.0) / 299_792_458.0
        elif form == "range_sum_m":
            d["range_sum_m"] = (val("rb") or 0.0) + 8005.6
        elif form != "none":
            d[str(form)] = val("rb")
        vform = rng.choice(["bistatic_velocity_mps", "doppler_hz", "none"])
        if vform != "none":
            d[str(vform)] = val("vb")
        for s in ("sigma_rb_m", "sigma_az_deg", "sigma_el_deg", "sigma_vb_mps"):
            if rng.random() < 0.7:
                d[s] = val("sig")
        plots.append(BistaticPlot.model_construct(**d))  # type: ignore[arg-type]
    cfg = PclTrackerConfig()
    wl = 3.06 if seed % 3 else None
    got = normalise_plots(plots, cfg, 8005.6, wl)
    ids, z, rejected, flagged, rows = scalar_reference(plots, cfg, 8005.6, wl)
    assert got.ids == ids
    np.testing.assert_array_equal(got.z, z)
    np.testing.assert_array_equal(got.sig, np.array([r[2] for r in rows]).reshape(-1, 4))
    np.testing.assert_array_equal(got.low_rb, np.array([r[3] for r in rows], dtype=bool))
    assert got.rejected == rejected and got.flagged == flagged
