"""The honest decision statistic of the LBL estimator (issue 16) against independent computations, its preset,
and its behaviour under bad input.

1. ``evidence.fit`` (Laplace evidence at the MAP trajectory, banded Gauss-Newton) against a brute-force integral
   of the exact likelihood over each half-plane of the beacon line, on tiny cases written here from Eq. (1)-(2).
2. The same statistic against ``bounds.exact_log_ratio_at`` (a Kalman filter linearised at the truth and its
   mirror) on the issue's 3 deg track.
3. The ``preset`` field: the paper's rule and the honest rule, from the configuration, the service's environment
   and the mc plugin's parameters.
4. Hypothesis property tests: the core and the service handler under extreme and invalid inputs never raise
   anything but the documented refusal, and a refused input leaves the state as if it had never been sent.
5. A small Monte-Carlo of the decision rules on the near-collinear family (the full size is in
   ``bench/bench_lbl_nearcollinear.py``).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import replace
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.special import logsumexp
from scipy.stats import beta

from schemas import BeaconRange, Depth, Header, Heading, Message, SpeedLog
from schemas.base import MAX_STAMP_NS
from schemas.lbl_nav import LblEvent, LblFix
from services.lbl_nav.bounds import NoiseModel, exact_log_ratio_at
from services.lbl_nav.config import LblNavConfig
from services.lbl_nav.core import LblNavCore
from services.lbl_nav.decision import ExactDecision, evidence_epoch
from services.lbl_nav.evidence import EvidenceEpoch, Priors, RangeObs, Record, Start, fit
from services.lbl_nav.offline import run_core, scenario_config
from services.lbl_nav.simulation import SimBeacon, SimRun, s2_spec, s3_spec, simulate
from services.lbl_nav.simulator import sim_params
from services.player.scenario import load_scenario
from shared.errors import InputRejected

B1, B2 = (0.0, 0.0, 100.0), (0.0, 1500.0, 100.0)
Z_AUV = 30.0
C = 1500.0


# ---- 1. brute force on tiny cases -------------------------------------------------------------------------------
def _tiny(
    seed: int, n: int, heading_deg: float, dK_true: float, two_every: int, bend_deg: float = 0.0
) -> tuple[list[EvidenceEpoch], np.ndarray, np.ndarray]:
    """A vehicle at 4 m/s on a track bent by ``bend_deg`` (a constant heading error dK_true between the true and
    the measured heading), one range to B1 per epoch and both beacons every ``two_every`` epochs, range noise of the
    digest's model (sigma_delta 5, sigma_v 10) and dc = 1.5 m/s. Returns the record, the measured DR displacement
    per epoch (ve, vn) and the true positions."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=np.float64)
    k_true = np.radians(heading_deg + bend_deg * np.sin(t / n * math.pi))
    k_meas = k_true - dK_true
    ve, vn = 4.0 * np.sin(k_meas), 4.0 * np.cos(k_meas)
    xy = np.column_stack([300.0 + np.cumsum(4.0 * np.sin(k_true)), 200.0 + np.cumsum(4.0 * np.cos(k_true))])
    epochs = []
    for k in range(n):
        delta = 5.0 * rng.standard_normal()
        obs = []
        for b in (B1, B2) if k % two_every == 0 else (B1,):
            D = math.dist((xy[k, 0], xy[k, 1], Z_AUV), b)
            y = D + 1.5 * D / C + delta + 10.0 * rng.standard_normal()
            obs.append(RangeObs(b[0], b[1], b[2], Z_AUV, y, 1.0 / C))
        epochs.append(EvidenceEpoch(1.0, float(ve[k]), float(vn[k]), ranges=tuple(obs)))
    return epochs, np.column_stack([ve, vn]), xy


def _brute_force_log_ratio(
    epochs: list[EvidenceEpoch], dr: np.ndarray, sigma_dK: float, grid: int, half_width_m: float, xy0: np.ndarray
) -> float:
    """ln p(Y | x_0 east of the line) - ln p(Y | west), the vehicle's track rigid (no log noise, constant dK, no
    current): integrate the exact likelihood of every range (Eq. 1) over x_0 on a grid around the truth and its
    mirror, over dK on a grid (if sigma_dK > 0) with its Gaussian prior, and over the constant dc analytically
    (the ranges are linear in dc: with e = y - D, T = D / c~, a = sum T^T R^-1 T and b = sum T^T R^-1 e over the
    epochs, integrating N(dc; 0, sigma_dc^2) adds 1/2 b^2 / (1/sigma_dc^2 + a) - 1/2 ln(1 + sigma_dc^2 a))."""
    n = len(epochs)
    s_dc2 = 9.0
    dks = np.linspace(-6.0 * sigma_dK, 6.0 * sigma_dK, 73) if sigma_dK > 0 else np.zeros(1)
    out = []
    for side in (1.0, -1.0):
        centre = np.array([side * xy0[0], xy0[1]])
        g = np.linspace(-half_width_m, half_width_m, grid)
        gx, gy = np.meshgrid(centre[0] + g, centre[1] + g, indexing="ij")
        cell = (g[1] - g[0]) ** 2
        terms = []
        for dk in dks:
            c, s = math.cos(dk), math.sin(dk)
            # positions of epoch k relative to epoch 0: the measured DR rotated by dK (true = measured + dK)
            steps = np.column_stack([dr[:, 0] * c + dr[:, 1] * s, dr[:, 1] * c - dr[:, 0] * s])
            steps[0] = 0.0
            offs = np.cumsum(steps, axis=0)
            q0 = np.zeros_like(gx)
            a = np.zeros_like(gx)
            b = np.zeros_like(gx)
            const = 0.0
            for k in range(n):
                obs = epochs[k].ranges
                m = len(obs)
                R = 25.0 * np.ones((m, m)) + 100.0 * np.eye(m)  # sigma_delta^2 1 1^T + sigma_v^2 I
                Ri = np.linalg.inv(R)
                const += math.log(np.linalg.det(2.0 * math.pi * R))
                D = np.stack(
                    [
                        np.sqrt((gx + offs[k, 0] - o.bx) ** 2 + (gy + offs[k, 1] - o.by) ** 2 + (o.z - o.bz) ** 2)
                        for o in obs
                    ]
                )
                e = np.stack([np.full_like(gx, o.y) for o in obs]) - D
                T = D / C
                Rie = np.einsum("ij,jxy->ixy", Ri, e)
                RiT = np.einsum("ij,jxy->ixy", Ri, T)
                q0 += np.sum(e * Rie, axis=0)
                a += np.sum(T * RiT, axis=0)
                b += np.sum(T * Rie, axis=0)
            ll = -0.5 * (q0 + const) + 0.5 * b * b / (1.0 / s_dc2 + a) - 0.5 * np.log1p(s_dc2 * a)
            prior = -0.5 * (dk / sigma_dK) ** 2 if sigma_dK > 0 else 0.0
            half = np.where(side * gx > 0.0, ll, -np.inf)  # the hypothesis: x_0 on this side of the line x = 0
            terms.append(float(logsumexp(half)) + math.log(cell) + prior)
        out.append(float(logsumexp(terms)))
    return out[0] - out[1]


def _priors(sigma_dK: float) -> Priors:
    """Nearly rigid tracks: log noise 0.02 m/s (a random walk of 0.12 m over 40 epochs, which ranges with
    sigma = 11 m cannot resolve: it changes the evidence by far less than the tolerances below) and dK constant:
    tau = 1e7 s lets it drift by sigma sqrt(2 n / tau) < 3e-4 rad over the record, far below its posterior width."""
    return Priors(5.0, 10.0, 3.0, 0.02, sigma_dK, 0.0, 1e7, 1e7)


def _batch_log_ratio(epochs: list[EvidenceEpoch], pri: Priors, xy_last: np.ndarray) -> float:
    rec = Record(epochs, pri)
    east = fit(rec, Start(float(xy_last[0]), float(xy_last[1])))
    west = fit(rec, Start(-float(xy_last[0]), float(xy_last[1])))
    assert east.converged and west.converged
    return east.log_evidence - west.log_evidence


def test_exact_evidence_equals_a_brute_force_integral_without_heading_error() -> None:
    """Unknowns x_0 (2) and dc. Tolerance 0.05 nats: what remains is the range curvature over the posterior
    (a few metres at ranges of 300-1500 m: D'' sigma^2 / 2 < 0.05 m against sigma_range = 11 m) and the grid
    (2 m cells against a posterior sd of about 10 m); the ratio itself is several nats."""
    epochs, dr, xy = _tiny(seed=3, n=30, heading_deg=10.0, dK_true=0.0, two_every=10)
    batch = _batch_log_ratio(epochs, _priors(0.0), xy[-1])
    brute = _brute_force_log_ratio(epochs, dr, 0.0, 301, 150.0, xy[0])
    assert abs(batch) > 2.0, batch  # a decisive-enough case for the comparison to mean something
    assert batch == pytest.approx(brute, abs=0.05)


def test_exact_evidence_equals_a_brute_force_integral_with_a_heading_error() -> None:
    """Unknowns x_0, dK (exact rotation of the log displacement, Gaussian prior 5 deg) and dc; the true heading
    error is 4 deg, and the mirror needs about -10 deg. Tolerance 0.05 nats: as above plus the grids (4 m cells;
    73 dK nodes over +/- 6 sigma, 0.8 deg apart, against posteriors of dK about 2 deg wide)."""
    sk = math.radians(5.0)
    epochs, dr, xy = _tiny(seed=4, n=30, heading_deg=5.0, dK_true=math.radians(4.0), two_every=10, bend_deg=5.0)
    batch = _batch_log_ratio(epochs, _priors(sk), xy[-1])
    brute = _brute_force_log_ratio(epochs, dr, sk, 91, 180.0, xy[0])
    assert abs(batch) > 1.0, batch
    assert batch == pytest.approx(brute, abs=0.05)


# ---- 2. against the truth-linearised filter of bounds.py ------------------------------------------------------
def test_exact_ratio_matches_the_truth_linearised_reference_on_the_3_degree_track() -> None:
    """The honest statistic (no truth: Gauss-Newton from the EKF's estimates) and the reference of bounds.py
    (Kalman filter linearised at the truth and at its mirror, heading terms at the true dK and at the dK the
    mirror needs) on the same data: all buffered epochs and the first 60 s after launch. Tolerance 0.1 decade:
    the two differ only by where the ranges are linearised (MAP vs truth, a few metres apart: range curvature
    d^2 / 2D < 0.1 m per row against sigma = 11 m)."""
    spec = s3_spec(3.0)
    cfg = scenario_config("S3", preset="honest")
    for seed in (70_001, 70_002, 70_003):
        sim = simulate(replace(spec, t_end_s=60.0), np.random.default_rng(seed), seed)
        core = LblNavCore(cfg)
        for m in sim.messages:
            with contextlib.suppress(InputRejected):
                core.step(m)
        core.flush()
        bank = core.bank
        assert bank is not None and len(bank.hyps) == 2 and bank.exact is not None
        ex = bank.exact
        lr = ex.check((_start(bank.hyps[0].X), _start(bank.hyps[1].X)))
        assert lr is not None
        i0 = sim.i0
        true_id = (
            1
            if np.hypot(*(bank.hyps[0].current()[0][:2] - (sim.x_m[-1], sim.y_m[-1])))
            < np.hypot(*(bank.hyps[1].current()[0][:2] - (sim.x_m[-1], sim.y_m[-1])))
            else 2
        )
        ours = lr.log_ratio if true_id == 1 else -lr.log_ratio
        ref = exact_log_ratio_at(sim, NoiseModel.of(spec), i0 + 60)
        assert ours / math.log(10) == pytest.approx(ref / math.log(10), abs=0.1), seed


def _start(X: np.ndarray) -> Start:
    from services.lbl_nav.decision import start_of

    return start_of(X)


# ---- 3. presets -------------------------------------------------------------------------------------------------
def test_presets_set_the_decision_rule_unless_fields_are_given(monkeypatch: pytest.MonkeyPatch) -> None:
    assert LblNavConfig().preset == "honest"
    assert (LblNavConfig().decision_statistic, LblNavConfig().robust_prior_scale) == ("exact", 2.0)
    paper = LblNavConfig(preset="paper")
    assert (paper.decision_statistic, paper.robust_prior_scale) == ("ekf", 1.0)
    assert LblNavConfig(preset="paper", decision_statistic="exact").decision_statistic == "exact"
    assert LblNavConfig(preset="honest", robust_prior_scale=3.0).robust_prior_scale == 3.0
    with pytest.raises(ValueError, match="preset"):
        LblNavConfig(preset="fast")  # type: ignore[arg-type]
    # the service's environment
    from services.lbl_nav import service as lbl_service

    monkeypatch.setenv("FIXSTREAM_LBL_NAV_INSTANCE", "auv7")
    assert lbl_service.build().core_config.decision_statistic == "exact"
    monkeypatch.setenv("FIXSTREAM_LBL_NAV_PRESET", "paper")
    cfg = lbl_service.build().core_config
    assert (cfg.preset, cfg.decision_statistic, cfg.robust_prior_scale) == ("paper", "ekf", 1.0)
    # the mc plugin's parameters (what a scenario file's estimators[].params.config sets)
    from services.lbl_nav.mc import Params

    assert Params(config={"preset": "paper"}).core_config("v").decision_statistic == "ekf"
    assert Params().core_config("v").decision_statistic == "exact"


def test_paper_preset_decides_on_the_ekf_ratio_and_honest_on_the_exact_one() -> None:
    """S2 (35 deg, a yaw before launch): both presets decide correctly; the paper's rule when the EKF ratio
    crosses 10^4 (a few epochs into the catch-up), the honest one at launch, on the exact ratio of all 97
    buffered epochs, which the bound of the EKF trigger leaves beyond the threshold."""
    sim = simulate(s2_spec(), np.random.default_rng(10_005), 10_005)
    paper = run_core(scenario_config("S2", preset="paper"), sim)
    honest = run_core(scenario_config("S2", preset="honest"), sim)
    for tr in (paper, honest):
        assert tr.decided is not None and not tr.wrong
    dp = next(e for e in paper.events if e.kind == "decision")
    dh = next(e for e in honest.events if e.kind == "decision")
    assert dp.reason == "ekf" and dh.reason == "exact" and "robust" in dh.detail
    assert honest.resolution_t_s is not None and paper.resolution_t_s is not None
    assert honest.resolution_t_s <= paper.resolution_t_s
    assert abs(dh.log10_ratio or 0.0) >= 4.0 and abs(dp.log10_ratio or 0.0) >= 4.0


def test_a_failing_exact_evaluation_makes_no_decision_and_leaves_the_filters_alone(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    sim = simulate(replace(s3_spec(3.0), t_end_s=30.0), np.random.default_rng(10_006), 10_006)

    def broken(*_a: Any, **_k: Any) -> Any:
        raise np.linalg.LinAlgError("forced")

    monkeypatch.setattr("services.lbl_nav.decision.fit", broken)
    honest = LblNavCore(scenario_config("S3", preset="honest", ratio_threshold=1e30))
    paper = LblNavCore(scenario_config("S3", preset="paper", ratio_threshold=1e30))
    for m in sim.messages:
        a: list[Message] = []
        b: list[Message] = []
        with contextlib.suppress(InputRejected):
            a = honest.step(m)
        with contextlib.suppress(InputRejected):
            b = paper.step(m)
        assert [type(o) for o in a] == [type(o) for o in b]
    assert honest.bank is not None and honest.bank.exact is not None and honest.bank.exact.failures >= 1
    assert paper.bank is not None and len(honest.bank.hyps) == len(paper.bank.hyps) == 2
    for h, p in zip(honest.bank.hyps, paper.bank.hyps, strict=True):
        np.testing.assert_array_equal(h.X, p.X)
        np.testing.assert_array_equal(h.P, p.P)


def test_record_is_not_usable_with_rows_that_are_not_ranges() -> None:
    from services.lbl_nav.models import DrInterval, LinearRow

    dr = DrInterval(1.0, 0.0, 4.0)
    assert evidence_epoch(dr, [LinearRow("s", 0, 0, "L", 1.0, 0.0, 1.0, 0.0, 0.0)]) is None
    ex = ExactDecision(LblNavConfig(), [evidence_epoch(dr, []), None])
    assert not ex.usable and not ex.due(1e9)


# ---- 4. property tests: bad input never breaks the core or the handler -------------------------------------------
@cache
def _base_messages() -> tuple[Message, ...]:
    """A short S2 run (launch at 20 s, 25 s after it): buffering, launch, the honest decision and tracking."""
    spec = replace(s2_spec(), t_start_s=-20.0, t_end_s=25.0)
    return tuple(simulate(spec, np.random.default_rng(10_007), 10_007).messages)


FINITE_EXTREME = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, -1e-300, 1e300, -1e300, 5e-324, 1e15, -1e15]),
)
#: stamps up to the schema's bound (MAX_STAMP_NS = 2**62): the decoder refuses anything beyond before a core sees it
STAMPS = st.one_of(
    st.integers(min_value=0, max_value=MAX_STAMP_NS),
    st.sampled_from([0, 1, MAX_STAMP_NS - 1, MAX_STAMP_NS, 2**61]),
)


@st.composite
def bad_message(draw: st.DrawFn) -> tuple[int, Message]:
    """An index into the base stream and a message to insert there: a copy of a nearby message with extreme or
    invalid values, an unknown beacon, a duplicate, a stamp going backwards or one near the schema's 2**62 bound
    (built without validation where the schema would refuse it: the core must survive what a decoder might let
    through)."""
    base = _base_messages()
    i = draw(st.integers(min_value=2, max_value=len(base) - 1))
    ref = base[i]
    stamp = ref.header.stamp_ns
    kind = draw(st.sampled_from(["range", "unknown", "dup", "back", "far", "log", "heading", "depth"]))
    h = Header(stamp_ns=stamp)
    if kind == "range":
        v = draw(FINITE_EXTREME)
        return i, BeaconRange.model_construct(header=h, beacon_id="B1", range_m=v, travel_time_s=None)
    if kind == "unknown":
        bid = draw(st.sampled_from(["B9", "", "b1", "B1 "]))
        return i, BeaconRange.model_construct(header=h, beacon_id=bid, range_m=900.0, travel_time_s=None)
    if kind == "dup":
        return i, ref
    if kind == "back":
        back = Header(stamp_ns=max(0, stamp - draw(st.integers(min_value=1, max_value=10**11))))
        return i, SpeedLog(header=back, v_forward_mps=4.0, v_starboard_mps=0.0, avg_interval_s=1.0)
    if kind == "far":
        return i, Depth(header=Header(stamp_ns=draw(STAMPS)), depth_m=30.0)
    v = draw(FINITE_EXTREME)
    if kind == "log":
        return i, SpeedLog.model_construct(header=h, v_forward_mps=v, v_starboard_mps=0.0, avg_interval_s=1.0)
    if kind == "heading":
        return i, Heading.model_construct(header=h, heading_rad=v)
    return i, Depth.model_construct(header=h, depth_m=v)


def _step_all(core: LblNavCore, msgs: list[Message]) -> tuple[list[Message], dict[int, str]]:
    outs: list[Message] = []
    refused: dict[int, str] = {}
    for j, m in enumerate(msgs):
        try:
            outs += core.step(m)
        except InputRejected as exc:
            refused[j] = exc.reason
    return outs + core.flush(), refused


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(data=st.data())
def test_core_survives_extreme_and_invalid_inputs_with_its_state_intact(data: st.DataObject) -> None:
    """Only InputRejected comes out of ``step``; every refused input leaves the core as if it had never been sent
    (a twin fed only the accepted inputs publishes the same outputs); every published covariance is finite and
    symmetric. One documented exception: the pre-launch range-rate gate remembers the range it refused (two
    consecutive mutually consistent ranges that contradict the anchor replace it, digest 5.4), so the twin is
    also sent the ranges refused for ``range_rate`` and must refuse exactly those."""
    base = _base_messages()
    inserts = data.draw(st.lists(bad_message(), min_size=1, max_size=4))
    msgs = list(base)
    for i, m in sorted(inserts, key=lambda x: -x[0]):
        msgs.insert(i, m)
    cfg = LblNavConfig(N_max=97, sigma_dK_rad=0.0, sigma_dU_mps=0.0, validate_outputs=True)
    outs, refused = _step_all(LblNavCore(cfg), msgs)
    kept = [j for j in range(len(msgs)) if refused.get(j, "range_rate") == "range_rate"]
    twin, twin_refused = _step_all(LblNavCore(cfg), [msgs[j] for j in kept])
    assert {kept[j]: r for j, r in twin_refused.items()} == {j: r for j, r in refused.items() if r == "range_rate"}
    assert twin == outs
    for o in outs:
        if isinstance(o, LblFix) and o.state is not None:
            P = np.array(o.state.covariance)
            assert np.all(np.isfinite(P)) and np.array_equal(P, P.T)


@settings(max_examples=10, deadline=None)
# integers within msgpack's range (the test packs the map itself; what msgpack cannot encode never reaches the wire)
@given(
    payload=st.one_of(
        st.binary(max_size=64),
        st.dictionaries(st.text(max_size=8), st.integers(min_value=-(2**63), max_value=2**64 - 1), max_size=4),
    )
)
def test_service_handler_refuses_garbage_and_counts_it(payload: Any) -> None:
    """Random bytes or msgpack maps on a sensor key: refused with a reason, never raised, counters add up."""
    import msgpack
    from stack_support import counters_add_up, offline_on_bytes

    from services.lbl_nav.service import LblNavService, LblNavSettings
    from services.lbl_nav.simulator import sensor_keys

    svc = LblNavService(LblNavSettings(instance="lbl1"))
    body = payload if isinstance(payload, bytes) else msgpack.packb(payload)
    from shared import codec

    enc = codec.encoding_of(BeaconRange)
    items = [(sensor_keys("lbl1")[name], body, enc) for name in ("BeaconRange", "SpeedLog", "Heading")]
    offline_on_bytes(svc, items)
    counters_add_up(svc)
    assert svc.counters.rejected + svc.counters.accepted == len(items)
    assert svc.core.state == "WAITING" or svc.counters.accepted > 0


# ---- 5. a small Monte-Carlo ---------------------------------------------------------------------------------------
SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"
#: runs of lbl_nav_nc_0p5 (seed = scenario seed * 10^6 + run) in which the paper's rule decided wrongly in the
#: 1,000-run bench (bench/bench_lbl_nearcollinear.py; docs/lbl_nav.md): the regression set of the honest rule
PAPER_WRONG_0P5 = (1601000241, 1601000424, 1601000477, 1601000490, 1601000749, 1601000760)


def _family_run(name: str, seed: int) -> SimRun:
    spec = sim_params(load_scenario(SCENARIOS / f"{name}.yaml")).spec()
    return simulate(spec, np.random.default_rng(seed), seed)


def test_runs_the_paper_rule_decides_wrongly_are_not_decided_wrongly_by_the_honest_rule() -> None:
    """A track 0.5 deg off the beacon line: in these runs rule (6) on the EKF ratio accepts the mirror (negative
    control, checked here too), the honest rule must not (the exact ratio with the doubled priors stays inside
    the threshold: evidence that rests on the heading prior's tail)."""
    for seed in PAPER_WRONG_0P5[:1]:
        sim = _family_run("lbl_nav_nc_0p5", seed)
        paper = run_core(scenario_config("S3", preset="paper"), sim, stop_when_resolved=True)
        assert paper.wrong, seed
        honest = run_core(scenario_config("S3", preset="honest"), sim, stop_when_resolved=True)
        assert not honest.wrong, seed


def test_no_wrong_decision_on_a_small_near_collinear_sample() -> None:
    """12 fresh runs of the issue's 3 deg track with the honest rule: 0 wrong decisions. At the digest's rate
    (S1.a: at most 1 in 1,500) the chance of one or more in 12 runs is 1 - (1 - 1/1500)^12 = 0.8 %, so the test
    fails by chance rarely; it is a smoke test of the rule on fresh data (its power against the paper's 0.3 % at
    3 deg is only 4 %), the regression run above is the sharp one. The full-size figures are the bench's (1,000
    runs per geometry)."""
    wrong = 0
    for seed in range(1_603_900_000, 1_603_900_012):
        tr = run_core(scenario_config("S3", preset="honest"), _family_run("lbl_nav_nc_3", seed), True)
        wrong += tr.wrong
    assert wrong == 0


def test_binomial_upper_bound_helper_of_the_bench() -> None:
    from services.lbl_nav.metrics import binomial_upper95 as upper95

    assert upper95(0, 1500) == pytest.approx(1.0 - 0.05 ** (1 / 1500), rel=1e-9)  # Clopper-Pearson, k = 0
    assert upper95(1, 300) == pytest.approx(float(beta.ppf(0.95, 2, 299)))
    assert upper95(3, 3) == 1.0


_ = (LblEvent, SimBeacon)
