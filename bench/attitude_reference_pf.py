"""A near-optimal reference for the attitude estimator (issue 15): a Rao-Blackwellised particle filter.

A scoring reference, not a shipped estimator: it answers whether the default preset's IMM
(``services/attitude/imm.py``) leaves accuracy on the table on the manoeuvring family, or whether the issue's
targets are beyond what a causal estimator can get from the plots. It shares nothing with the IMM but the
measurement model (eq. 1, ``geometry.convert_plot``) and the generic Kalman/resampling helpers of
``shared/filters``.

**Model** (a jump-Markov, conditionally linear system; Chen & Liu 2000 "mixture Kalman filter", Doucet, Gordon &
Krishnamurthy 2001). Frame E (x north, y up, z east). Per particle a discrete regime r and a turn rate omega;
given their path the kinematic state

    s = [x, z, Vx, Vz, bx, bz, y, Vy, by]     (m, m/s, m/s^2)

is linear-Gaussian and is carried by a Kalman filter per particle:

    x' = Vx,  z' = Vz,  y' = Vy
    Vx' = -omega Vz + bx,   Vz' = +omega Vx + bz,   Vy' = by        (psi = atan2(Vz, Vx), psi' = omega)
    b' = -b / tau + w   (regimes S, T: the wander, an Ornstein-Uhlenbeck acceleration)
    b' = w              (regime M: a random-walk acceleration with jumps)

The 9-state of the schema is a linear map of s given omega: a_x = bx - omega Vz, a_z = bz + omega Vx, a_y = by.

Regimes (what ``services/attitude/flights.py`` flies):

* **S, straight**: omega = 0. The wander of the generator (``flights.WANDER``): OU, tau = 20 s, 0.2 m/s^2 across
  the path and vertically, 0.05 m/s^2 along it (the noise's horizontal directions frozen at the particle's
  heading at the start of each sub-step).
* **T, coordinated turn**: omega constant (a small random walk keeps the particles diverse), the same wander.
  Entered from S at a turn onset with omega = g tan(bank) / V_h: the bank drawn from the generator's banks at the
  particle's speed (below 135 m/s the light aircraft's U(15, 45) deg; above, the transport's U(10, 30) deg or,
  with probability 0.25, the agile flights' 60 deg), either sign. The turn ends (back to S) after a heading change
  drawn from the generator's U(60, 240) deg (U(90, 180) deg at 60 deg of bank): the hazard of that distribution
  given the heading change flown so far, which the particle carries.
* **M, other manoeuvre** (climb entries and exits, pull-ups, zero-g arcs, pull-outs): omega = 0; the
  acceleration jumps by N(0, sigma_jump^2) along the path and vertically at the onset and at a rate 1 / 8 s
  inside, and walks with a small white jerk in between. Back to S after an exponential sojourn, with the
  acceleration reset to the wander's stationary law (level flight again).
* Onsets from S: an exponential straight sojourn whose mean matches the family's (about 42 onsets in about
  9,800 s of straight flight: 230 s), half turns, half other manoeuvres. Flights start straight.

Regime changes happen on a sub-step grid (1 s), so a 3-5 s roll-in is a jump of omega at its middle. Given the
regime path the prediction is exact: Phi(omega) = expm(A(omega) dt) and Q by Van Loan's integral, tabulated on
an omega grid (step 2e-4 rad/s: 0.03 deg of heading per 5 s scan at most).

**Filter**: the regime path sampled per sub-step from the prior, except that onsets are proposed
``onset_proposal_boost`` times as often (weights p / q for a switch, (1 - p) / (1 - q) for a stay); exact Kalman
prediction and update per particle (the converted plot z, R_z of eq. 1 measures the position), weights by the
innovation likelihood N(nu; 0, S); when the effective sample size falls below half, systematic resampling
stratified by regime, with at least ``min_share_turn`` / ``min_share_manoeuvre`` of the particles kept in T / M
(weights W_r / n_r: the posterior is unchanged; a turn that has just begun keeps particles until the plots decide).
``turn_exit_sojourn_s`` and ``turn_vertical_jerk_mps3`` are ablations, not the generator's law.
The output is the first two moments of the posterior mixture of the 9-state, sum_i w_i N(T_i s_i, T_i P_i T_i^T):
the same (alpha, P) the IMM reports, to which the same angle block (eqs. 4-5) is applied.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import expm

from shared.filters.resampling import effective_sample_size

F64 = NDArray[np.float64]

#: regimes
S, T, M = 0, 1, 2
#: indices of s: horizontal block [x, z, Vx, Vz, bx, bz] and vertical block [y, Vy, by]
H_IDX = slice(0, 6)
V_IDX = slice(6, 9)
#: the measured position [x, y, z] (frame E order) in s
POS = np.array([0, 6, 1])
#: b in s (horizontal x, z and vertical)
B_IDX = np.array([4, 5, 8])


@dataclass(frozen=True)
class ManoeuvrePrior:
    """The prior of the reference filter: the statistics of ``services/attitude/flights.py`` (defaults), as a
    designer who knows the generator but not the flights would set them. Units in the names."""

    # the wander (flights.WANDER)
    sigma_lat_mps2: float = 0.2
    sigma_vert_mps2: float = 0.2
    sigma_long_mps2: float = 0.05
    tau_s: float = 20.0
    # onsets from straight flight
    straight_sojourn_s: float = 230.0
    p_turn: float = 0.5
    # turns: banks by speed, heading change
    light_speed_max_mps: float = 135.0
    light_bank_deg: tuple[float, float] = (15.0, 45.0)
    transport_bank_deg: tuple[float, float] = (10.0, 30.0)
    agile_bank_deg: tuple[float, float] = (59.0, 61.0)
    p_agile: float = 0.25  # of the turns above light_speed_max_mps
    heading_change_deg: tuple[float, float] = (60.0, 240.0)
    agile_heading_change_deg: tuple[float, float] = (90.0, 180.0)
    omega_walk_rps_sqrts: float = 5e-4  # random walk of a turn's rate (particle diversity, speed drift)
    # ablations (not the generator's law): a memoryless turn exit of this mean sojourn instead of the heading-change
    # law; a white vertical jerk in turns (the vertical acceleration a random walk) instead of the wander
    turn_exit_sojourn_s: float | None = None
    turn_vertical_jerk_mps3: float | None = None
    onset_proposal_boost: float = 10.0  # onsets are proposed this many times as often (importance weights)
    min_share_turn: float = 0.25  # particles kept in the turn regime at a resampling (stratified; weights adjust)
    min_share_manoeuvre: float = 0.1
    resample_ess_share: float = 0.5  # resample when the effective sample size is below this share of N
    # other manoeuvres
    manoeuvre_sojourn_s: float = 14.0
    sigma_jump_mps2: float = 5.0
    jump_interval_s: float = 8.0
    sigma_jerk_manoeuvre_mps3: float = 0.5
    # numerics and constants
    substep_s: float = 1.0
    omega_max_rps: float = 0.3
    omega_step_rps: float = 2e-4
    g_mps2: float = 9.81
    # the start (plot 1): diffuse velocity, level flight, the stationary wander
    sigma_v0_h_mps: float = 300.0
    sigma_v0_v_mps: float = 20.0


def van_loan(a: F64, g: F64, dt_s: float) -> tuple[F64, F64]:
    """Phi = expm(A dt) and Q = int_0^dt expm(A s) g g^T expm(A s)^T ds (unit white-noise intensity), batched
    over the leading axes of ``a`` (..., n, n); ``g`` (n,) is the noise input (Van Loan 1978)."""
    n = a.shape[-1]
    big = np.zeros((*a.shape[:-2], 2 * n, 2 * n))
    big[..., :n, :n] = -a
    big[..., :n, n:] = np.outer(g, g)
    big[..., n:, n:] = np.swapaxes(a, -1, -2)
    e = expm(big * dt_s)
    phi = np.swapaxes(e[..., n:, n:], -1, -2)
    q = phi @ e[..., :n, n:]
    return phi, 0.5 * (q + np.swapaxes(q, -1, -2))


def horizontal_a(omega: F64, tau_s: float) -> F64:
    """A(omega) of [x, z, Vx, Vz, bx, bz] (..., 6, 6); tau_s = inf: a random-walk b."""
    w = np.asarray(omega, dtype=np.float64)
    a = np.zeros((*w.shape, 6, 6))
    a[..., 0, 2] = a[..., 1, 3] = 1.0
    a[..., 2, 3] = -w
    a[..., 3, 2] = w
    a[..., 2, 4] = a[..., 3, 5] = 1.0
    a[..., 4, 4] = a[..., 5, 5] = -1.0 / tau_s
    return a


def vertical_a(tau_s: float) -> F64:
    """A of [y, Vy, by] (3, 3)."""
    return np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0 / tau_s]])


#: the horizontal rotation by +90 deg (e_x -> e_z) on every (x, z) pair of [x, z, Vx, Vz, bx, bz]
ROT90 = np.kron(np.eye(3), np.array([[0.0, -1.0], [1.0, 0.0]]))


@dataclass(frozen=True)
class Tables:
    """Transitions of one sub-step dt for every omega of the grid (regimes S, T) and for regime M."""

    omega: F64  # (G,)
    phi_h: F64  # (G, 6, 6)
    k_xx: F64  # (G, 6, 6): Q of unit noise intensity on bx
    k_zz: F64  # on bz (= R k_xx R^T)
    k_xz: F64  # the cross term of a noise along (cos, sin): k_xx R^T + R k_xx
    phi_v: F64  # (3, 3)
    k_v: F64  # (3, 3) unit intensity on by
    phi_hm: F64  # (6, 6) regime M
    k_hm: F64  # (6, 6) unit intensity on bx and on bz
    phi_vm: F64
    k_vm: F64
    stacked: F64  # (G, 4, 6, 6): phi_h, k_xx, k_zz, k_xz (one gather per sub-step)


@functools.lru_cache(maxsize=8)
def tables(prior: ManoeuvrePrior, dt_s: float) -> Tables:
    """The transition tables of a sub-step of dt_s (cached per prior and step)."""
    n = round(prior.omega_max_rps / prior.omega_step_rps)
    omega = prior.omega_step_rps * np.arange(-n, n + 1, dtype=np.float64)
    e_bx = np.eye(6)[4]
    phi_h, k_xx = van_loan(horizontal_a(omega, prior.tau_s), e_bx, dt_s)
    rt = ROT90.T
    k_zz = ROT90 @ k_xx @ rt
    k_xz = k_xx @ rt + ROT90 @ k_xx
    phi_v, k_v = van_loan(vertical_a(prior.tau_s), np.eye(3)[2], dt_s)
    phi_hm, k_hx = van_loan(horizontal_a(np.zeros(()), math.inf), e_bx, dt_s)
    phi_vm, k_vm = van_loan(vertical_a(math.inf), np.eye(3)[2], dt_s)
    stacked = np.ascontiguousarray(np.stack([phi_h, k_xx, k_zz, k_xz], axis=1))
    return Tables(omega, phi_h, k_xx, k_zz, k_xz, phi_v, k_v, phi_hm, k_hx + ROT90 @ k_hx @ rt, phi_vm, k_vm, stacked)


def inverse_3x3(a: F64) -> tuple[F64, F64]:
    """(a^-1, det a) of a batch of symmetric 3x3 matrices (N, 3, 3), by the adjugate."""
    a00, a01, a02 = a[:, 0, 0], a[:, 0, 1], a[:, 0, 2]
    a11, a12, a22 = a[:, 1, 1], a[:, 1, 2], a[:, 2, 2]
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    inv = np.stack([c00, c01, c02, c01, c11, c12, c02, c12, c22], axis=-1).reshape(-1, 3, 3) / det[:, None, None]
    return inv, det


class ReferencePF:
    """The Rao-Blackwellised particle filter of one target (module docstring). ``start`` with the first plot,
    then ``step`` with each further plot; ``moments`` gives the posterior mean and covariance of the 9-state
    [x Vx ax y Vy ay z Vz az]."""

    def __init__(self, prior: ManoeuvrePrior, n_particles: int, rng: np.random.Generator) -> None:
        self.prior = prior
        self.n = n_particles
        self.rng = rng
        self.t_s = math.nan
        self.s = np.zeros((n_particles, 9))
        self.p = np.zeros((n_particles, 9, 9))
        self.logw = np.zeros(n_particles)
        self.regime = np.zeros(n_particles, dtype=np.int8)
        self.omega_idx = np.zeros(n_particles, dtype=np.intp)
        self.turned_deg = np.zeros(n_particles)  # heading change flown in the current turn
        self.agile = np.zeros(n_particles, dtype=bool)
        self.resamples = 0
        self._zero_idx = round(prior.omega_max_rps / prior.omega_step_rps)
        self.omega_grid = prior.omega_step_rps * np.arange(-self._zero_idx, self._zero_idx + 1, dtype=np.float64)

    # ------------------------------------------------------------------ start
    def start(self, t_s: float, z: F64, rz: F64) -> None:
        """The prior at plot 1: position from the plot, a diffuse horizontal velocity, level flight, the wander's
        stationary acceleration; every particle straight."""
        pr = self.prior
        s = np.zeros(9)
        s[POS] = z
        p = np.zeros((9, 9))
        p[np.ix_(POS, POS)] = rz
        p[2, 2] = p[3, 3] = pr.sigma_v0_h_mps**2
        p[7, 7] = pr.sigma_v0_v_mps**2
        p[4, 4] = p[5, 5] = 0.5 * (pr.sigma_lat_mps2**2 + pr.sigma_long_mps2**2)
        p[8, 8] = pr.sigma_vert_mps2**2
        self.s[:] = s
        self.p[:] = p
        self.logw[:] = 0.0
        self.regime[:] = S
        self.omega_idx[:] = self._zero_idx
        self.t_s = t_s

    # ------------------------------------------------------------------ one plot
    def step(self, t_s: float, z: F64, rz: F64) -> float:
        """Predict to t_s in sub-steps and update with the plot; returns the effective sample size before any
        resampling."""
        dt = t_s - self.t_s
        n_sub = max(1, round(dt / self.prior.substep_s))
        tab = tables(self.prior, round(dt / n_sub, 9))
        for _ in range(n_sub):
            self._substep(tab, dt / n_sub)
        self._update(z, rz)
        self.t_s = t_s
        w = self.weights()
        ess = effective_sample_size(w)
        if ess < self.prior.resample_ess_share * self.n:
            self._resample(w)
        return ess

    def weights(self) -> F64:
        w = np.exp(self.logw - self.logw.max())
        return w / w.sum()

    def _resample(self, w: F64) -> None:
        """Regime-stratified systematic resampling: regime r gets n_r = max(N W_r, N min_share_r) particles (the
        straight regime the rest), drawn within r by its weights and each weighted W_r / n_r, so that a
        hypothesis of small probability (a turn that has just begun) keeps enough particles until the plots
        decide it; the posterior is unchanged (the weights carry it)."""
        pr = self.prior
        shares = {T: pr.min_share_turn, M: pr.min_share_manoeuvre}
        counts: dict[int, int] = {}
        mass: dict[int, float] = {}
        for r in (T, M):
            mass[r] = float(w[self.regime == r].sum())
            counts[r] = 0 if mass[r] <= 0.0 else max(round(self.n * mass[r]), round(self.n * shares[r]))
        mass[S] = float(w[self.regime == S].sum())
        counts[S] = self.n - counts[T] - counts[M]
        if mass[S] <= 0.0 or counts[S] < 1:  # no straight particle: give its count to the heavier regime
            heavy = T if mass[T] >= mass[M] else M
            counts[heavy] += counts[S]
            counts[S] = 0
        parts: list[NDArray[np.intp]] = []
        logw: list[F64] = []
        for r, n_r in counts.items():
            if n_r <= 0:
                continue
            members = np.flatnonzero(self.regime == r)
            wr = w[members] / mass[r]
            u = (self.rng.random() + np.arange(n_r)) / n_r  # systematic, within the regime
            pick = members[np.minimum(np.searchsorted(np.cumsum(wr), u), members.size - 1)]
            parts.append(pick)
            logw.append(np.full(n_r, math.log(mass[r] / n_r)))
        idx = np.concatenate(parts)
        self.logw = np.concatenate(logw)
        self.s = self.s[idx]
        self.p = self.p[idx]
        self.regime = self.regime[idx]
        self.omega_idx = self.omega_idx[idx]
        self.turned_deg = self.turned_deg[idx]
        self.agile = self.agile[idx]
        self.logw -= self.logw.max()
        self.resamples += 1

    # ------------------------------------------------------------------ regimes
    def _b_jump(self, rows: NDArray[np.intp], cov_h: F64, var_v: float) -> None:
        """Add a zero-mean acceleration jump: cov_h (k, 2, 2) horizontally, var_v vertically."""
        hb = np.array([4, 5])
        self.p[rows[:, None, None], hb[None, :, None], hb[None, None, :]] += cov_h
        self.p[rows, 8, 8] += var_v

    def _transitions(self, dt: float) -> None:
        pr = self.prior
        rng = self.rng
        u = rng.random(self.n)
        reg = self.regime
        vx, vz = self.s[:, 2], self.s[:, 3]
        vh = np.maximum(np.hypot(vx, vz), 1.0)
        c, sn = vx / vh, vz / vh
        # S -> T or M, proposed at a boosted rate q and weighted by p / q (switch) or (1 - p) / (1 - q) (stay)
        straight = reg == S
        p_on = -math.expm1(-dt / pr.straight_sojourn_s)
        q_on = min(0.5, pr.onset_proposal_boost * p_on)
        onset = straight & (u < q_on)
        if q_on > 0.0:
            stay = math.log1p(-p_on) - math.log1p(-q_on)
            self.logw += np.where(onset, math.log(p_on / q_on), np.where(straight, stay, 0.0))
        to_turn = onset & (rng.random(self.n) < pr.p_turn)
        to_man = onset & ~to_turn
        # T -> S: the hazard of the heading change's uniform law given the change so far
        turning = reg == T
        lo = np.where(self.agile, pr.agile_heading_change_deg[0], pr.heading_change_deg[0])
        hi = np.where(self.agile, pr.agile_heading_change_deg[1], pr.heading_change_deg[1])
        done = self.turned_deg
        step_deg = np.abs(self.omega_grid[self.omega_idx]) * dt * 180.0 / math.pi
        f0 = np.clip((done - lo) / (hi - lo), 0.0, 1.0)
        f1 = np.clip((done + step_deg - lo) / (hi - lo), 0.0, 1.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            hazard = np.where(f0 < 1.0, (f1 - f0) / (1.0 - f0), 1.0)
        if pr.turn_exit_sojourn_s is not None:
            hazard = np.full(self.n, -math.expm1(-dt / pr.turn_exit_sojourn_s))
        end_turn = turning & (u < hazard)
        # M -> S, or a jump inside M
        man = reg == M
        end_man = man & (u < -math.expm1(-dt / pr.manoeuvre_sojourn_s))
        jump = man & ~end_man & (rng.random(self.n) < -math.expm1(-dt / pr.jump_interval_s))

        # new turns: bank by speed, either sign
        k = np.flatnonzero(to_turn)
        if k.size:
            light = vh[k] < pr.light_speed_max_mps
            agile = ~light & (rng.random(k.size) < pr.p_agile)
            banks = np.where(
                light[:, None], pr.light_bank_deg, np.where(agile[:, None], pr.agile_bank_deg, pr.transport_bank_deg)
            )
            lo_b, hi_b = banks[:, 0], banks[:, 1]
            bank = np.radians(lo_b + (hi_b - lo_b) * rng.random(k.size))
            sign = np.where(rng.random(k.size) < 0.5, -1.0, 1.0)
            self.omega_idx[k] = self._index(sign * pr.g_mps2 * np.tan(bank) / vh[k])
            self.turned_deg[k] = 0.0
            self.agile[k] = agile
            self.regime[k] = T
        # turns going on: the rate's random walk
        k = np.flatnonzero(turning & ~end_turn)
        if k.size:
            steps = pr.omega_walk_rps_sqrts * math.sqrt(dt) * rng.standard_normal(k.size)
            self.omega_idx[k] = self._index(self.omega_grid[self.omega_idx[k]] + steps)
        k = np.flatnonzero(end_turn)
        self.omega_idx[k] = self._zero_idx
        self.regime[k] = S
        # manoeuvres: jumps along the path and vertically at the onset and inside
        k = np.flatnonzero(to_man | jump)
        if k.size:
            e = np.stack([c[k], sn[k]], axis=-1)
            self._b_jump(k, pr.sigma_jump_mps2**2 * e[:, :, None] * e[:, None, :], pr.sigma_jump_mps2**2)
        self.regime[to_man] = M
        # the end of a manoeuvre: the acceleration is the wander's again (level flight)
        k = np.flatnonzero(end_man)
        if k.size:
            self.s[np.ix_(k, B_IDX)] = 0.0
            self.p[k[:, None], B_IDX[None, :], :] = 0.0
            self.p[k[:, None], :, B_IDX[None, :]] = 0.0
            self.p[k[:, None, None], np.array([4, 5])[None, :, None], np.array([4, 5])[None, None, :]] = self._wander_h(
                c[k], sn[k]
            )
            self.p[k, 8, 8] = pr.sigma_vert_mps2**2
            self.regime[k] = S

    def _wander_h(self, c: F64, s: F64) -> F64:
        """The wander's stationary horizontal covariance (k, 2, 2) at headings (cos, sin)."""
        pr = self.prior
        e_lon = np.stack([c, s], axis=-1)
        e_lat = np.stack([-s, c], axis=-1)
        return pr.sigma_long_mps2**2 * e_lon[:, :, None] * e_lon[:, None, :] + pr.sigma_lat_mps2**2 * (
            e_lat[:, :, None] * e_lat[:, None, :]
        )

    def _index(self, omega: F64) -> NDArray[np.intp]:
        pr = self.prior
        i = np.rint(omega / pr.omega_step_rps).astype(np.intp) + self._zero_idx
        return np.clip(i, 0, 2 * self._zero_idx)

    # ------------------------------------------------------------------ prediction and update
    def _substep(self, tab: Tables, dt: float) -> None:
        """Sample the regime changes of one sub-step, then the exact Kalman prediction of every particle given its
        regime and turn rate: s <- Phi s, P <- Phi P Phi^T + Q (Q of the wander: q_lon along the heading at the
        sub-step's start, q_lat across it; of the white jerk in regime M)."""
        pr = self.prior
        self._transitions(dt)
        man = self.regime == M
        vx, vz = self.s[:, 2], self.s[:, 3]
        vh = np.hypot(vx, vz)
        moving = vh > 0.0
        vh = np.where(moving, vh, 1.0)
        # the heading's (cos^2, sin^2, cos sin); no heading (V_h = 0, the start): the isotropic mean
        c2 = np.where(moving, (vx / vh) ** 2, 0.5)
        s2 = np.where(moving, (vz / vh) ** 2, 0.5)
        cs = np.where(moving, vx * vz / (vh * vh), 0.0)
        q_lat = 2.0 * pr.sigma_lat_mps2**2 / pr.tau_s
        q_lon = 2.0 * pr.sigma_long_mps2**2 / pr.tau_s
        q_v = 2.0 * pr.sigma_vert_mps2**2 / pr.tau_s
        q_m = pr.sigma_jerk_manoeuvre_mps3**2
        idx = self.omega_idx
        h = tab.stacked[idx]  # (N, 4, 6, 6): Phi_h, K_xx, K_zz, K_xz
        w = np.stack([q_lon * c2 + q_lat * s2, q_lon * s2 + q_lat * c2, (q_lon - q_lat) * cs])
        phi = np.zeros((self.n, 9, 9))
        q = np.zeros((self.n, 9, 9))
        phi[:, H_IDX, H_IDX] = h[:, 0]
        q[:, H_IDX, H_IDX] = np.einsum("kn,nkij->nij", w, h[:, 1:])
        phi[:, V_IDX, V_IDX] = tab.phi_v
        q[:, V_IDX, V_IDX] = q_v * tab.k_v
        if pr.turn_vertical_jerk_mps3 is not None:
            turn = self.regime == T
            phi[turn, V_IDX, V_IDX] = tab.phi_vm
            q[turn, V_IDX, V_IDX] = pr.turn_vertical_jerk_mps3**2 * tab.k_vm
        if man.any():
            phi[man, H_IDX, H_IDX] = tab.phi_hm
            q[man, H_IDX, H_IDX] = q_m * tab.k_hm
            phi[man, V_IDX, V_IDX] = tab.phi_vm
            q[man, V_IDX, V_IDX] = q_m * tab.k_vm
        self.s = (phi @ self.s[:, :, None])[:, :, 0]
        self.p = phi @ self.p @ np.swapaxes(phi, 1, 2) + q  # symmetrised after the update
        turning = self.regime == T
        self.turned_deg[turning] += np.abs(tab.omega[idx[turning]]) * dt * 180.0 / math.pi

    def _update(self, z: F64, rz: F64) -> None:
        """Kalman update of every particle with the converted plot; log-weights += ln N(nu; 0, S)."""
        pht = self.p[:, :, POS]  # P H^T (N, 9, 3)
        s_mat = pht[:, POS, :] + rz
        s_mat = 0.5 * (s_mat + np.swapaxes(s_mat, 1, 2))
        s_inv, det = inverse_3x3(s_mat)
        nu = z - self.s[:, POS]
        s_nu = np.einsum("nij,nj->ni", s_inv, nu)
        k = pht @ s_inv
        self.s = self.s + np.einsum("nij,nj->ni", k, nu)
        p = self.p - k @ np.swapaxes(pht, 1, 2)
        self.p = 0.5 * (p + np.swapaxes(p, 1, 2))
        self.logw += -0.5 * (np.einsum("ni,ni->n", nu, s_nu) + np.log(det))
        self.logw -= self.logw.max()

    # ------------------------------------------------------------------ output
    def transforms(self) -> F64:
        """T_i (N, 9, 9): s -> [x Vx ax y Vy ay z Vz az] given each particle's omega."""
        om = self.omega_grid[self.omega_idx]
        t = np.zeros((self.n, 9, 9))
        t[:, 0, 0] = 1.0  # x
        t[:, 1, 2] = 1.0  # Vx
        t[:, 2, 4] = 1.0  # ax = bx - omega Vz
        t[:, 2, 3] = -om
        t[:, 3, 6] = 1.0  # y
        t[:, 4, 7] = 1.0  # Vy
        t[:, 5, 8] = 1.0  # ay = by
        t[:, 6, 1] = 1.0  # z
        t[:, 7, 3] = 1.0  # Vz
        t[:, 8, 5] = 1.0  # az = bz + omega Vx
        t[:, 8, 2] = om
        return t

    def moments(self, mask: NDArray[np.bool_] | None = None) -> tuple[F64, F64]:
        """Mean (9,) and covariance (9, 9) of the posterior mixture of the 9-state (of the particles in ``mask``
        only, renormalised, if given)."""
        w = self.weights()
        if mask is not None:
            w = np.where(mask, w, 0.0)
            w = w / w.sum()
        t = self.transforms()
        y = np.einsum("nij,nj->ni", t, self.s)
        mean = w @ y
        d = y - mean
        cov = np.einsum("n,nij->ij", w, t @ self.p @ np.swapaxes(t, 1, 2)) + (d * w[:, None]).T @ d
        return mean, 0.5 * (cov + cov.T)

    def regime_probabilities(self) -> F64:
        w = self.weights()
        return np.array([w[self.regime == r].sum() for r in (S, T, M)])
