"""The components of rd_nav's filter step (issue 19): each checked on its own against an independent computation.

The behaviour of the whole step (gate, rescue, update, re-initiation, EKF shadow, fixes) is pinned by
tests/test_rd_nav_core.py and the bit-identical ``fixstream mc`` outputs of the refactor; these tests pin the
pieces: the late-arrival test of §4.11 against its closed form with S = sigma^2 I, the rescue policy's memory,
the condition number against numpy's SVD, and the fix builder's positive-definite covariance.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from services.rd_nav.config import RdNavConfig
from services.rd_nav.fixes import FilterState, FixBuilder, FixContent
from services.rd_nav.gate import condition_number
from services.rd_nav.rescue import LateArrivalRescue, one_late_arrival

GATES = {m: float(chi2.ppf(0.999, m)) for m in range(1, 17)}


def _ids(M: int) -> list[str]:
    return ["lead", *(f"f{j}" for j in range(M))]


@settings(max_examples=60, deadline=None)
@given(
    M=st.integers(2, 6),
    k=st.integers(0, 5),
    b_sigmas=st.floats(5.0, 200.0),
    sigma_m=st.floats(0.1, 10.0),
)
def test_a_late_follower_is_named_and_the_rest_passes(M: int, k: int, b_sigmas: float, sigma_m: float) -> None:
    """e = b u_k with S = sigma^2 I: g = u_k gives z = (b / sigma)^2 = NIS, so the rest is 0 and T drops row k; the
    leader hypothesis (g = -1) has g^T S^-1 e = -b / sigma^2 < 0 (an advance) and is refused."""
    k = k % M
    b = b_sigmas * sigma_m
    e = np.zeros(M)
    e[k] = b
    late = one_late_arrival(e, sigma_m**2 * np.eye(M), _ids(M), GATES[1], GATES)
    assert late is not None and late.arrival_id == f"f{k}"
    assert abs(late.nis_rest) <= 1e-9 * b_sigmas**2
    g = np.eye(M)[k]
    np.testing.assert_allclose(late.T @ g, 0.0, atol=0.0)
    assert late.T.shape == (M - 1, M)


@settings(max_examples=60, deadline=None)
@given(M=st.integers(2, 6), b_sigmas=st.floats(5.0, 200.0), sigma_m=st.floats(0.1, 10.0))
def test_a_late_leader_lowers_every_difference(M: int, b_sigmas: float, sigma_m: float) -> None:
    """e = -b 1 (the leader late by b): g = -1 explains it all (z = M b^2 / sigma^2 = NIS); T 1 = 0 (leader-free
    differences)."""
    b = b_sigmas * sigma_m
    e = -b * np.ones(M)
    late = one_late_arrival(e, sigma_m**2 * np.eye(M), _ids(M), GATES[1], GATES)
    assert late is not None and late.arrival_id == "lead"
    assert abs(late.nis_rest) <= 1e-9 * M * b_sigmas**2
    np.testing.assert_allclose(late.T @ np.ones(M), 0.0, atol=0.0)


def test_a_residual_inside_the_one_dimensional_gate_is_not_a_late_arrival() -> None:
    """z <= chi2_1 (here 3 sigma on one follower, 9 < 10.83): nothing to explain away."""
    e = np.array([3.0, 0.0])
    assert one_late_arrival(e, np.eye(2), _ids(2), GATES[1], GATES) is None


def test_the_same_arrival_is_not_dropped_twice_in_a_row() -> None:
    rescue = LateArrivalRescue(GATES)
    e, S, ids = np.array([50.0, 0.0]), np.eye(2), _ids(2)
    first = rescue.explain(e, S, ids)
    assert first is not None and first.arrival_id == "f0"
    rescue.remember(first.arrival_id)
    assert rescue.explain(e, S, ids) is None
    rescue.remember(None)  # a cycle used whole in between
    again = rescue.explain(e, S, ids)
    assert again is not None and again.arrival_id == "f0"


@settings(max_examples=100, deadline=None)
@given(
    rows=st.lists(
        st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)).filter(lambda r: abs(r[0]) + abs(r[1]) > 1e-3),
        min_size=2,
        max_size=6,
    )
)
def test_condition_number_matches_the_singular_values(rows: list[tuple[float, float]]) -> None:
    H = np.array(rows)
    sv = np.linalg.svd(H, compute_uv=False)
    if sv[-1] < 1e-6 * sv[0]:
        return  # near-singular: both are huge, the closed form may say inf
    kappa = sv[0] / sv[-1]
    # the closed form takes the small eigenvalue of H^T H as mid - rad: a cancellation that loses about u kappa^2 of
    # its relative precision (u the unit round-off), half of that in kappa; Hypothesis found kappa = 6.6e5 off by
    # 7.6e-6 relative, inside this bound (3.8e-4) and far outside 1e-6
    rtol = max(1e-9, 4.0 * np.finfo(float).eps * kappa**2)
    np.testing.assert_allclose(condition_number(H), kappa, rtol=rtol)


@settings(max_examples=60, deadline=None)
@given(ax=st.floats(-5.0, 5.0), ay=st.floats(-5.0, 5.0), nis=st.sampled_from([None, 1.5, float("nan"), float("inf")]))
def test_a_collapsed_cloud_reports_a_positive_definite_covariance(ax: float, ay: float, nis: float | None) -> None:
    """P = a a^T (rank 1, or 0) is reported positive definite; a non-finite NIS is reported as missing; the beacons
    are listed only for a used cycle."""
    a = np.array([ax, ay])
    builder = FixBuilder(RdNavConfig(auv_id="auv9"))
    state = FilterState(initialised=True, depth_m=None, reinit_count=2, cycles_since_update=0)
    for cycle_status in ("USED", "REJECTED"):
        content = FixContent(
            "PF", "CYCLE", 10**9, np.zeros(2), np.outer(a, a), "TRACKING", 500.0,
            cycle_status=cycle_status, beacons=["lead", "f0"], nis=nis, flags=["B", "A", "B"],
        )  # fmt: skip
        fix = builder.build(content, state)
        assert np.linalg.eigvalsh(np.array(fix.estimate.covariance)).min() > 0.0
        assert fix.nis == (nis if nis is not None and np.isfinite(nis) else None)
        assert fix.beacons_used == (["lead", "f0"] if cycle_status == "USED" else [])
        assert fix.flags == ["A", "B"] and fix.depth_m == 0.0 and fix.valid


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    M=st.integers(2, 5),
)
def test_the_dr_error_jacobian_is_the_derivative_of_the_compensated_prediction(seed: int, M: int) -> None:
    """h_j(p, delta_j - G_j e): central differences in e (an independent computation) against
    error_jacobian(follower_units, G), used by the gate, the PF weights and the EKF shadow. (It once took the
    full dh/dp row u_j - u_1 in place of u_j: the leader's range does not move with delta_j.)"""
    from services.rd_nav.geometry import error_jacobian, follower_units, predict_d

    rng = np.random.default_rng(seed)
    p = rng.uniform(-800.0, 800.0, (1, 2))
    leader = np.array([*rng.uniform(-1500.0, 1500.0, 2), 10.0])
    followers = np.column_stack([rng.uniform(-1500.0, 1500.0, (M, 2)), rng.uniform(5.0, 50.0, M)])
    delta = rng.normal(0.0, 20.0, (M, 2))
    G = rng.normal(0.0, 30.0, (M, 2, 3))
    z1, zj = 40.0, rng.uniform(20.0, 60.0, M)

    def h(e: np.ndarray) -> np.ndarray:
        comp = delta - np.einsum("mij,j->mi", G, e)
        return predict_d(p, leader, followers, comp, z1, zj)[0]

    step = 1e-4
    numeric = np.column_stack([(h(step * u) - h(-step * u)) / (2 * step) for u in np.eye(3)])
    analytic = error_jacobian(follower_units(p[0], zj, delta, followers), G)
    np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-7)
