"""Issue 15: the reference particle filter (bench/attitude_reference_pf.py) against answers known in closed form.

* One linear model (no manoeuvre can start): every particle carries the same Kalman filter, so the posterior mean
  and covariance must be a Kalman filter's on the same plots, with F = expm(A dt) and Q by quadrature of
  expm(A s) G q G^T expm(A s)^T built here (not by the reference's Van Loan tables), through
  ``shared/filters/kalman.py`` (tolerance: rounding).
* Two static hypotheses (straight, or a turn at a known rate; no switching): the exact posterior is the
  two-component Gaussian mixture of two such Kalman filters weighted by their plots' likelihoods; the particle
  filter (regime-stratified resampling) must match its turn probability and mean within Monte-Carlo tolerance.
* The transition tables: Phi(omega) equals expm of the continuous model at every sampled rate, the rotation
  identities for K_zz and K_xz hold.
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm

from services.attitude.config import MeasurementSigmas
from services.attitude.geometry import convert_plot
from services.attitude.simulation import FlightPlan, Segment, fly, measure, paper_plan, scan_times
from shared.filters import kalman

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository root: the reference is bench code
from bench.attitude_reference_pf import ManoeuvrePrior, ReferencePF, S, T, tables

SIGMAS = MeasurementSigmas(sigma_r_m=225.0, sigma_az_deg=0.35, sigma_el_deg=0.3)
D2R = math.pi / 180.0
#: a prior without any regime change: a straight flight is one linear model
NO_SWITCH = ManoeuvrePrior(straight_sojourn_s=math.inf, heading_change_deg=(1e9, 2e9), omega_walk_rps_sqrts=0.0)


def plots(plan: FlightPlan, n_scans: int, seed: int) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """(t s, z, R_z) of the converted plots of a flight (eq. 1)."""
    t = scan_times(n_scans)
    meas = measure(fly(plan, t), SIGMAS, np.random.default_rng(seed))[0]
    out = []
    for tk, (r, az, el) in zip(t.tolist(), meas.tolist(), strict=True):
        z, rz = convert_plot(
            r, az * D2R, el * D2R, SIGMAS.sigma_r_m, SIGMAS.sigma_az_deg * D2R, SIGMAS.sigma_el_deg * D2R
        )
        out.append((tk, z, rz))
    return out


# ---------------------------------------------------------------- an independent Kalman filter of the same model
def continuous_a(omega: float, tau_s: float) -> np.ndarray:
    """A of the 9-state [x Vx ax y Vy ay z Vz az] written directly (not the reference's layout): a = b + omega x V
    horizontally, b an OU acceleration; here the state holds b, so the output map adds omega x V."""
    a = np.zeros((9, 9))
    for p_, v_, b_ in ((0, 1, 2), (3, 4, 5), (6, 7, 8)):
        a[p_, v_] = 1.0
        a[v_, b_] = 1.0
        a[b_, b_] = -1.0 / tau_s
    a[1, 7] = -omega  # Vx' = -omega Vz + bx
    a[7, 1] = omega  # Vz' = +omega Vx + bz
    return a


def simpson_nodes(a: np.ndarray, dt: float, n: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """Simpson's rule on [0, dt] (n even): the weights and expm(A s) at the nodes."""
    s = np.linspace(0.0, dt, n + 1)
    w = np.ones(n + 1)
    w[1:-1:2], w[2:-1:2] = 4.0, 2.0
    return w * dt / (3 * n), expm(a[None] * s[:, None, None])


def quadrature_q(
    a: np.ndarray, qc: np.ndarray, dt: float, nodes: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """int_0^dt expm(A s) Qc expm(A s)^T ds by Simpson's rule."""
    w, e = nodes if nodes is not None else simpson_nodes(a, dt)
    return np.einsum("k,kij,jl,kml->im", w, e, qc, e)


def output_map(omega: float) -> np.ndarray:
    """[x Vx bx y Vy by z Vz bz] -> [x Vx ax y Vy ay z Vz az]."""
    t = np.eye(9)
    t[2, 7] = -omega
    t[8, 1] = omega
    return t


class ModelKf:
    """A Kalman filter of one regime (straight: omega = 0, or a turn at a known omega) on the 9-state with the
    wander's noise along / across the heading frozen at each sub-step's start (as the reference does)."""

    def __init__(self, prior: ManoeuvrePrior, omega: float, t0: float, z: np.ndarray, rz: np.ndarray) -> None:
        self.prior, self.omega, self.t = prior, omega, t0
        self.x = np.zeros(9)
        self.x[[0, 3, 6]] = z
        self.p = np.zeros((9, 9))
        self.p[np.ix_([0, 3, 6], [0, 3, 6])] = rz
        self.p[1, 1] = self.p[7, 7] = prior.sigma_v0_h_mps**2
        self.p[4, 4] = prior.sigma_v0_v_mps**2
        self.p[2, 2] = self.p[8, 8] = 0.5 * (prior.sigma_lat_mps2**2 + prior.sigma_long_mps2**2)
        self.p[5, 5] = prior.sigma_vert_mps2**2
        self.loglik = 0.0
        self.a = continuous_a(omega, prior.tau_s)
        self.f = expm(self.a * prior.substep_s)
        self.nodes = simpson_nodes(self.a, prior.substep_s)

    def _q(self, vx: float, vz: float) -> np.ndarray:
        """Q of one sub-step with the horizontal noise along / across the heading of (vx, vz) (no heading: the
        mean of the two)."""
        pr = self.prior
        q_lon, q_lat = 2 * pr.sigma_long_mps2**2 / pr.tau_s, 2 * pr.sigma_lat_mps2**2 / pr.tau_s
        qc = np.zeros((9, 9))
        vh = math.hypot(vx, vz)
        if vh > 0.0:
            e_lon, e_lat = np.array([vx, vz]) / vh, np.array([-vz, vx]) / vh
            qc[np.ix_([2, 8], [2, 8])] = q_lon * np.outer(e_lon, e_lon) + q_lat * np.outer(e_lat, e_lat)
        else:
            qc[2, 2] = qc[8, 8] = 0.5 * (q_lon + q_lat)
        qc[5, 5] = 2 * pr.sigma_vert_mps2**2 / pr.tau_s
        return quadrature_q(self.a, qc, pr.substep_s, self.nodes)

    def step(self, t: float, z: np.ndarray, rz: np.ndarray) -> None:
        for _ in range(round((t - self.t) / self.prior.substep_s)):
            self.x, self.p = kalman.predict(self.x, self.p, self.f, self._q(self.x[1], self.x[7]))
        h = np.zeros((3, 9))
        h[[0, 1, 2], [0, 3, 6]] = 1.0
        self.x, self.p, y, s_mat = kalman.update(self.x, self.p, z, h, rz)
        self.loglik += float(kalman.log_likelihood(y, s_mat))
        self.t = t

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        m = output_map(self.omega)
        return m @ self.x, m @ self.p @ m.T


# ---------------------------------------------------------------- tests
def test_tables_are_the_continuous_model() -> None:
    prior = ManoeuvrePrior()
    tab = tables(prior, 1.0)
    rot = np.kron(np.eye(3), np.array([[0.0, -1.0], [1.0, 0.0]]))
    for omega in (-0.13, -0.02, 0.0, 0.057, 0.2):
        i = int(np.argmin(np.abs(tab.omega - omega)))
        w = float(tab.omega[i])
        a = np.zeros((6, 6))  # [x z Vx Vz bx bz]
        a[0, 2] = a[1, 3] = a[2, 4] = a[3, 5] = 1.0
        a[2, 3], a[3, 2] = -w, w
        a[4, 4] = a[5, 5] = -1.0 / prior.tau_s
        np.testing.assert_allclose(tab.phi_h[i], expm(a), atol=1e-12)
        qc = np.zeros((6, 6))
        qc[4, 4] = 1.0
        np.testing.assert_allclose(tab.k_xx[i], quadrature_q(a, qc, 1.0), rtol=1e-7, atol=1e-14)
        np.testing.assert_allclose(tab.k_zz[i], rot @ tab.k_xx[i] @ rot.T, atol=1e-14)
        qc_xz = np.zeros((6, 6))
        qc_xz[4, 5] = qc_xz[5, 4] = 1.0
        np.testing.assert_allclose(tab.k_xz[i], quadrature_q(a, qc_xz, 1.0), rtol=1e-7, atol=1e-14)


@pytest.mark.parametrize("isotropic", [True, False])
def test_one_linear_model_is_a_kalman_filter(isotropic: bool) -> None:
    prior = NO_SWITCH if not isotropic else replace(NO_SWITCH, sigma_long_mps2=0.2)
    flight = plots(paper_plan(), 30, seed=4)
    pf = ReferencePF(prior, 40, np.random.default_rng(0))
    (t0, z0, r0), rest = flight[0], flight[1:]
    pf.start(t0, z0, r0)
    kf = ModelKf(prior, 0.0, t0, z0, r0)
    for t, z, rz in rest:
        pf.step(t, z, rz)
        kf.step(t, z, rz)
        assert np.all(pf.regime == S)
        x_pf, p_pf = pf.moments()
        x_kf, p_kf = kf.moments()
        scale = np.sqrt(np.diag(p_kf))
        np.testing.assert_allclose((x_pf - x_kf) / scale, 0.0, atol=1e-6)
        np.testing.assert_allclose(p_pf / np.outer(scale, scale), p_kf / np.outer(scale, scale), atol=1e-6)


def test_two_static_hypotheses_match_the_exact_mixture() -> None:
    """Straight or a 0.5 deg/s turn, prior 50/50, on a flight that turns at that rate from the start: the exact
    posterior is the mixture of the two Kalman filters; the particle filter's turn probability and mean agree
    within 4 Monte-Carlo standard errors of N particles (its regime-stratified resampling keeps each regime's
    mass, so the agreement is in fact to rounding)."""
    omega0 = math.radians(0.5)
    prior = replace(NO_SWITCH, resample_ess_share=1.01)  # resample at every plot
    plan = replace(paper_plan(), segments=(Segment(600.0, turn_rate_dps=(0.5, 0.5)),))
    flight = plots(plan, 20, seed=2)
    n = 400
    pf = ReferencePF(prior, n, np.random.default_rng(3))
    (t0, z0, r0), rest = flight[0], flight[1:]
    pf.start(t0, z0, r0)
    pf.regime[n // 2 :] = T
    pf.omega_idx[n // 2 :] = int(np.argmin(np.abs(pf.omega_grid - omega0)))
    omega_used = float(pf.omega_grid[pf.omega_idx[-1]])
    kfs = [ModelKf(prior, 0.0, t0, z0, r0), ModelKf(prior, omega_used, t0, z0, r0)]
    checked = 0
    for t, z, rz in rest:
        pf.step(t, z, rz)
        for kf in kfs:
            kf.step(t, z, rz)
        ll = np.array([kf.loglik for kf in kfs])
        w = np.exp(ll - ll.max())
        w /= w.sum()
        p_turn = float(w[1])
        moments = [kf.moments() for kf in kfs]
        mean = w[0] * moments[0][0] + w[1] * moments[1][0]
        pf_turn = float(pf.regime_probabilities()[1])
        se = math.sqrt(p_turn * (1.0 - p_turn) / n)
        assert abs(pf_turn - p_turn) <= 4.0 * se + 1e-9, (t, pf_turn, p_turn)
        x_pf, _ = pf.moments()
        gap = np.abs(moments[1][0] - moments[0][0])
        assert np.all(np.abs(x_pf - mean) <= 4.0 * se * gap + 1e-6 * (1.0 + np.abs(mean)))
        checked += 0.05 < p_turn < 0.95
    assert pf.resamples > 0  # the resampling was exercised
    assert checked >= 2  # and the data did not decide at once: the comparison had both hypotheses alive
    assert p_turn > 0.99  # in the end the turn is plain
