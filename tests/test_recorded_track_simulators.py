"""Recorded trajectories as truth in every simulator that moves a platform (issue 16): lbl_nav, rd_group,
attitude and pcl_tracker take ``track:`` (the shipped example tracks, scenarios/tracks/, written by
``python -m tools.example_tracks``).

For each: the published truth is the recorded track (rows read here with numpy, geodetic rows converted with
the closed-form WGS84 formulas of test_recorded_track, not PROJ), the sensor streams agree with that truth
within their noise, the platform stops with the track, the synthetic motion fields are refused next to a
track, and the estimator runs on the shipped scenario with an accuracy checked against a bound derived from
the noise or from its own covariance.
"""

from __future__ import annotations

import copy
import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from scipy.interpolate import CubicSpline
from test_foxglove import proto_class
from test_recorded_track import enu_independent

from schemas import BeaconRange, BeaconTable, Depth, Heading, RadarPlot, SpeedLog, Truth
from schemas.radar import BistaticScan
from services.attitude.simulator import AttitudeSimParams
from services.lbl_nav.simulation import simulate
from services.lbl_nav.simulator import LblSimParams, recorded_path
from services.pcl_tracker.simulator import PclSimParams
from services.player.scenario import Scenario, parse_scenario
from services.player.simulators import Event
from services.player.simulators.recorded_track import GeoPoint, load_cached, write_track_csv
from services.player.timeline import scenario_events
from services.rd_nav.simulation import ScenarioConfig
from services.rd_nav.simulator import RdGroupParams
from shared.foxglove.convert import Converter

REPO = Path(__file__).resolve().parents[1]
TRACKS = REPO / "scenarios" / "tracks"
NS = 1_000_000_000
ADSB_ORIGIN = GeoPoint(lat_deg=45.0, lon_deg=7.0, alt_m=0.0)
#: a track with smoothing none is a natural cubic spline through the rows: exact there up to float rounding
#: (and the closed-form geodesy agrees with PROJ to well below a micrometre)
EXACT_M = 1e-5


def rows(name: str) -> dict[str, np.ndarray]:
    """The columns of a shipped track file, read independently of the player's reader."""
    lines = [ln for ln in (TRACKS / name).read_text().splitlines() if ln and not ln.startswith("#")]
    header, body = lines[0].split(","), [ln.split(",") for ln in lines[1:]]
    out: dict[str, np.ndarray] = {}
    for k, col in enumerate(header):
        values = [row[k] for row in body]
        out[col] = np.array(values) if col == "time" else np.array([float(v) for v in values])
    return out


def adsb_enu() -> tuple[np.ndarray, np.ndarray]:
    """(t s from the first row, ENU at 45 N 7 E) of the ADS-B-like track."""
    r = rows("adsb_turn.csv")
    t = (r["time"].astype("datetime64[ns]") - r["time"][0].astype("datetime64[ns]")) / np.timedelta64(1, "s")
    enu = enu_independent(r["lat_deg"], r["lon_deg"], r["alt_m"], ADSB_ORIGIN)
    return np.asarray(t, dtype=np.float64), enu


def scenario(name: str, change: Any = None) -> Scenario:
    """A shipped scenario, optionally changed (``change(doc)`` edits the parsed YAML in place)."""
    doc = yaml.safe_load((REPO / "scenarios" / f"{name}.yaml").read_text())
    doc = copy.deepcopy(doc)
    if change is not None:
        change(doc)
    return parse_scenario(doc, name)


def truths(events: list[Event], platform: str) -> list[Truth]:
    return [ev.msg for ev in events if isinstance(ev.msg, Truth) and ev.msg.platform == platform]


def sim_params(doc: dict[str, Any], index: int = 0) -> dict[str, Any]:
    out: dict[str, Any] = doc["simulators"][index]["params"]
    return out


# ----- lbl_nav ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def lbl_events() -> list[Event]:
    return scenario_events(scenario("lbl_nav_recorded_track"), seed=3)


def test_lbl_truth_is_the_recorded_log_and_the_sensors_agree_with_it(lbl_events: list[Event]) -> None:
    r = rows("auv_lbl_stop.csv")
    tr = truths(lbl_events, "lbl1")
    t = np.array([m.header.stamp_ns / NS for m in tr])
    pos = np.array([m.position_m for m in tr])
    # one truth per epoch, every 1 s from the first row to the last (the simulator stops with the log)
    assert t[0] == 0.0 and t[-1] == pytest.approx(300.0) and np.allclose(np.diff(t), 1.0)
    np.testing.assert_allclose(pos, np.column_stack([r["east_m"], r["north_m"], r["up_m"]]), atol=EXACT_M, rtol=0)
    np.testing.assert_allclose([m.attitude_rad[0] for m in tr], np.radians(r["heading_deg"] % 360.0), atol=1e-9)
    assert max(ev.stamp_ns for ev in lbl_events) <= 300 * NS
    # depth: the recorded 30 m
    assert {m.depth_m for m in (ev.msg for ev in lbl_events) if isinstance(m, Depth)} == {30.0}
    # log and compass: with S2's sigma_dK = sigma_dU = 0 and no current, dead reckoning of the interval ending at
    # epoch i (log on the measured heading) reproduces the truth's step, up to the log noise (0.1 m/s, 1 s)
    logs = {ev.stamp_ns: ev.msg for ev in lbl_events if isinstance(ev.msg, SpeedLog)}
    heads = {ev.stamp_ns: ev.msg for ev in lbl_events if isinstance(ev.msg, Heading)}
    stamps = sorted(logs)
    assert len(stamps) == 301
    res = []
    for i in range(1, len(stamps)):
        lg, k = logs[stamps[i]], heads[stamps[i]].heading_rad
        de = lg.v_forward_mps * math.sin(k) + lg.v_starboard_mps * math.cos(k)
        dn = lg.v_forward_mps * math.cos(k) - lg.v_starboard_mps * math.sin(k)
        res.append([de - (pos[i, 0] - pos[i - 1, 0]), dn - (pos[i, 1] - pos[i - 1, 1])])
    res_a = np.array(res)
    assert np.max(np.abs(res_a)) < 5 * 0.1
    assert np.std(res_a) == pytest.approx(0.1, rel=0.15)  # 600 draws: the SD within 15 %
    # during the recorded stop (t = 110-140 s) the log reads the noise only
    stop = [logs[s].v_forward_mps for s in stamps if 111 * NS <= s <= 139 * NS]
    assert max(abs(v) for v in stop) < 5 * 0.1
    # ranges = slant distance to the beacon + dc D / c + delta + v (S2: 3 m/s, 5 m, 10 m)
    table = next(ev.msg for ev in lbl_events if isinstance(ev.msg, BeaconTable))
    beacons = {b.beacon_id: (b.x_east_m, b.y_north_m, b.depth_m) for b in table.beacons}
    at = {round(tt * NS): p for tt, p in zip(t, pos, strict=True)}
    errs = []
    for ev in lbl_events:
        if isinstance(ev.msg, BeaconRange) and ev.msg.range_m is not None:
            b, p = beacons[ev.msg.beacon_id], at[ev.stamp_ns]
            d = math.dist((b[0], b[1], b[2]), (p[0], p[1], -p[2]))
            errs.append(ev.msg.range_m - d)
    assert len(errs) > 250
    bound = 5 * math.hypot(5.0, 10.0) + 5 * 3.0 * 1200.0 / 1500.0  # 5 sigma of delta + v, 5 sigma of dc D / c
    assert max(abs(e) for e in errs) < bound


def test_lbl_estimator_on_the_recorded_log_stays_within_its_own_sigmas() -> None:
    from services.lbl_nav import mc

    sc = scenario("lbl_nav_recorded_track")
    params = sc.estimators[0].params
    for seed in (1, 2):
        out = mc.run_core(scenario_events(sc, seed=seed), {**params, "without_buffered": False}, sc)["with"]
        assert out["launched"] and not out["wrong"] and out["resolution_t_s"] is not None
        ex, ey = (np.array([np.nan if v is None else v for v in out[k]]) for k in ("err_x", "err_y"))
        sx, sy = (np.array([np.nan if v is None else v for v in out[k]]) for k in ("sd_x", "sd_y"))
        ok = np.isfinite(ex) & np.isfinite(sx)
        assert ok.sum() > 200  # fixes to the end of the log (240 s after launch)
        # each axis within 4 sigma of the filter's own covariance at every time (a Gaussian exceeds 4 sigma with
        # probability 6e-5 per draw; the ~240 errors of a run are strongly correlated)
        assert np.max(np.abs(ex[ok]) / sx[ok]) < 4.0
        assert np.max(np.abs(ey[ok]) / sy[ok]) < 4.0


@settings(max_examples=25, deadline=None)
@given(
    speeds=st.lists(st.floats(0.0, 3.0), min_size=4, max_size=4),
    headings=st.lists(st.floats(-180.0, 540.0), min_size=4, max_size=4),
    current=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)),
    dt=st.sampled_from([0.5, 1.0, 2.0]),
    offset=st.floats(0.0, 100.0),
)
def test_lbl_noise_free_log_reproduces_any_recorded_track(
    speeds: list[float], headings: list[float], current: tuple[float, float], dt: float, offset: float
) -> None:
    """Property: with every error sigma 0, dead reckoning of the log on the compass heading plus the known current
    gives back the recorded positions at every epoch (any speed profile, stops included, any heading, current, epoch
    period and time offset)."""
    t = np.arange(0.0, 60.0 + 1e-9, 0.5)
    knots = np.linspace(0.0, 60.0, 4)
    v, h = np.interp(t, knots, speeds), np.radians(np.interp(t, knots, headings))
    east = np.concatenate([[0.0], np.cumsum(0.5 * v[1:] * np.sin(h[1:]))])
    north = np.concatenate([[0.0], np.cumsum(0.5 * v[1:] * np.cos(h[1:]))])
    with tempfile.TemporaryDirectory() as d:
        path = write_track_csv(Path(d) / "t.csv", t, {"east_m": east, "north_m": north, "up_m": np.full(t.size, -20.0)})
        zero = {f"sigma_{n}": 0.0 for n in ("delta_m", "v_m", "dc_mps", "dV_mps", "dK_deg", "dU_mps")}
        params = LblSimParams.model_validate(
            {
                "preset": "s2",
                "pre_launch_s": 10.0,
                "dt_s": dt,
                "known_current_ne_mps": [current[0], current[1]],
                "track": {"path": str(path), "smoothing": "none", "time_offset_s": offset},
                **zero,
            }
        )
        spec = params.spec()
        assert params.track is not None
        track = load_cached(params.track)
        run = simulate(spec, np.random.default_rng(0), path=recorded_path(track, spec))
    assert run.stamps_ns[0] == round(offset * NS) and run.t_s[-1] + spec.epoch0_s <= offset + 60.0 + 1e-6
    logs = [m for m in run.messages if isinstance(m, SpeedLog)]
    heads = [m.heading_rad for m in run.messages if isinstance(m, Heading)]
    for i in range(1, len(logs)):
        k, lg = heads[i], logs[i]
        de = (lg.v_forward_mps * math.sin(k) + lg.v_starboard_mps * math.cos(k) + current[1]) * dt
        dn = (lg.v_forward_mps * math.cos(k) - lg.v_starboard_mps * math.sin(k) + current[0]) * dt
        assert de == pytest.approx(run.x_m[i] - run.x_m[i - 1], abs=1e-9)
        assert dn == pytest.approx(run.y_m[i] - run.y_m[i - 1], abs=1e-9)
    np.testing.assert_allclose(run.x_m, track.states(spec.epoch0_s + run.t_s).position_m[:, 0], atol=1e-9)


def test_lbl_track_excludes_the_synthetic_motion() -> None:
    base = {"platform": "lbl1", "preset": "s2", "pre_launch_s": 60, "track": {"path": str(TRACKS / "auv_lbl_stop.csv")}}
    LblSimParams.model_validate(base)
    for extra in ({"speed_mps": 3.0}, {"launch_xy_m": [0.0, 0.0]}, {"start_s": 5.0}, {"post_launch_s": 10.0}):
        with pytest.raises(ValidationError, match="track replaces the synthetic motion"):
            LblSimParams.model_validate({**base, **extra})
    with pytest.raises(ValidationError, match="longer than the recorded track"):
        LblSimParams.model_validate({**base, "pre_launch_s": 400})


# ----- attitude ---------------------------------------------------------------------------------------------


def _exact_adsb(doc: dict[str, Any]) -> None:
    doc["duration_s"] = 330
    sim_params(doc)["targets"][0]["track"]["smoothing"] = "none"


def test_attitude_truth_is_the_geodetic_track_and_plots_agree_with_it() -> None:
    sc = scenario("attitude_recorded_track", _exact_adsb)
    events = scenario_events(sc, seed=4)
    t_rows, enu = adsb_enu()
    tr = truths(events, "adsb1")
    t = np.array([m.header.stamp_ns / NS for m in tr])
    # a scan every 5 s, ending with the track at t = 300 s although the scenario runs to 330 s
    np.testing.assert_allclose(t, np.arange(0.0, 300.0 + 1e-9, 5.0))
    pos = np.array([m.position_m for m in tr])
    np.testing.assert_allclose(pos, enu[np.searchsorted(t_rows, t)], atol=EXACT_M, rtol=0)
    plots = [ev.msg for ev in events if isinstance(ev.msg, RadarPlot)]
    assert len(plots) == len(tr) and max(p.header.stamp_ns for p in plots) == 300 * NS
    # plots = true (range, azimuth, elevation) from the radar at the origin + 9S15 noise (225 m, 0.35, 0.3 deg)
    rng = np.linalg.norm(pos, axis=1)
    az = np.degrees(np.arctan2(pos[:, 0], pos[:, 1])) % 360.0
    el = np.degrees(np.arcsin(pos[:, 2] / rng))
    z = np.array(
        [
            [(p.range_m - r) / 225.0, ((p.az_deg - a + 180.0) % 360.0 - 180.0) / 0.35, (p.el_deg - e) / 0.3]
            for p, r, a, e in zip(plots, rng, az, el, strict=True)
        ]
    )
    assert np.max(np.abs(z)) < 5.0 and np.mean(z**2) == pytest.approx(1.0, abs=0.35)  # 183 draws


def test_attitude_truth_angles_follow_the_smoothed_track_in_the_estimators_convention() -> None:
    sc = scenario("attitude_recorded_track")
    events = scenario_events(sc, seed=4)
    tr = truths(events, "adsb1")
    t_rows, enu = adsb_enu()
    t = np.array([m.header.stamp_ns / NS for m in tr])
    pos = np.array([m.position_m for m in tr])
    # GCV smoothing: the truth stays within the noise of the rows (3 m per horizontal axis, 25 ft steps in
    # height, 2.2 m RMS): a smoothing spline's residual RMS is sigma sqrt(1 - tr(H)/n) < sigma
    d = pos - enu[np.searchsorted(t_rows, t)]
    assert np.sqrt(np.mean(d[:, :2] ** 2)) < 3.0 and np.sqrt(np.mean(d[:, 2] ** 2)) < 25 * 0.3048 / math.sqrt(12)
    v = np.array([m.velocity_mps for m in tr])
    a = np.array([m.acceleration_mps2 for m in tr])
    att = np.array([m.attitude_rad for m in tr])
    vh = np.hypot(v[:, 0], v[:, 1])
    np.testing.assert_allclose(att[:, 0], np.arctan2(v[:, 0], v[:, 1]) % (2 * math.pi), atol=1e-9)
    np.testing.assert_allclose(att[:, 1], np.arctan2(v[:, 2], vh), atol=1e-9)
    # roll of coordinated level flight: the specific force's lateral part v_h omega over its vertical part g + a_up
    omega = (v[:, 1] * a[:, 0] - v[:, 0] * a[:, 1]) / vh**2
    np.testing.assert_allclose(att[:, 2], np.arctan2(vh * omega, 9.81 + a[:, 2]), atol=math.radians(0.1))
    # the generating turn: 1.5 deg/s at 200 m/s = 28.1 deg of bank, held from t = 104 to 160 s
    turn = (t >= 110) & (t <= 155)
    assert np.degrees(att[turn, 2]) == pytest.approx(np.full(turn.sum(), 28.1), abs=3.0)
    assert np.degrees(att[t == 50, 0])[0] == pytest.approx(110.0, abs=0.5)
    assert np.degrees(att[t == 250, 0])[0] == pytest.approx(200.0, abs=0.5)


def test_attitude_heading_error_on_straight_legs_is_bounded_by_the_plot_noise() -> None:
    from services.attitude import mc

    sc = scenario("attitude_recorded_track")
    params = sc.estimators[0].params
    runs = [mc.run_core(scenario_events(sc, seed=s), params, sc) for s in (1, 2, 3)]
    agg = mc.aggregate(runs)["phases"]["steady"]
    # bound: the heading of a least-squares line through 5 scans (25 s) of the cross-range noise R sigma_az at
    # the track's farthest straight-leg range (39 km, 0.35 deg): sigma_v = R sigma_az sqrt(12 / (m (m^2 - 1))) / T,
    # sigma_psi = sigma_v / V; any filter that remembers at least 5 scans of a straight leg does better
    r_max, m, period, speed = 39_500.0, 5, 5.0, 200.0
    sigma_v = r_max * math.radians(0.35) * math.sqrt(12.0 / (m * (m * m - 1))) / period
    bound_deg = math.degrees(sigma_v / speed)
    assert agg["samples"] >= 60
    assert agg["rms_deg"]["psi"] < bound_deg
    assert agg["valid"]["psi"]["within_2sigma"] >= 0.9  # and consistent with its own sigma


def test_attitude_track_excludes_plan_start_segments_and_wander() -> None:
    track = {"path": str(TRACKS / "adsb_turn.csv"), "time_column": "time"}
    base = {"site_id": "r1", "targets": [{"id": "a", "track": track}]}
    AttitudeSimParams.model_validate(base)
    bad = [
        {"id": "a", "track": track, "plan": "paper"},
        {"id": "a", "track": track, "segments": [{"duration_s": 5.0}]},
        {"id": "a", "track": track, "wander": {}},
        {"id": "a", "track": {**track, "time_offset_s": 10.0}, "phase_s": 5.0},
    ]
    for target in bad:
        with pytest.raises(ValidationError):
            AttitudeSimParams.model_validate({**base, "targets": [target]})
    with pytest.raises(ValidationError, match="does not exist"):
        AttitudeSimParams.model_validate({**base, "targets": [{"id": "a", "track": {"path": "nope.csv"}}]})


# ----- pcl_tracker ------------------------------------------------------------------------------------------


def _only_adsb_exact(doc: dict[str, Any]) -> None:
    p = sim_params(doc)
    p["targets"] = p["targets"][:1]
    p["targets"][0]["track"]["smoothing"] = "none"
    p["p_detection"] = 1.0
    p["clutter"] = {"rate_per_scan": 0.0}


def test_pcl_truth_is_the_geodetic_track_and_plots_agree_with_it() -> None:
    sc = scenario("pcl_tracker_recorded_track", _only_adsb_exact)
    events = scenario_events(sc, seed=5)
    t_rows, enu = adsb_enu()
    tr = truths(events, "adsb1")
    t = np.array([m.header.stamp_ns / NS for m in tr])
    # a scan every 3 s while the track lasts (300 s), none after although the scenario runs to 330 s
    np.testing.assert_allclose(t, np.arange(0.0, 300.0 + 1e-9, 3.0))
    pos = np.array([m.position_m for m in tr])
    np.testing.assert_allclose(pos, enu[np.searchsorted(t_rows, t)], atol=EXACT_M, rtol=0)
    scans = [ev.msg for ev in events if isinstance(ev.msg, BistaticScan)]
    assert scans[-1].header.stamp_ns == 330 * NS and all(not s.plots for s in scans if s.header.stamp_ns > 300 * NS)
    # bistatic range r_b = |p| + |p - tx| - |tx| of the truth, + 200 m noise (digest 003)
    tx = np.array([8000.0, 0.0, 300.0])
    rb = np.linalg.norm(pos, axis=1) + np.linalg.norm(pos - tx, axis=1) - np.linalg.norm(tx)
    z = [(s.plots[0].bistatic_range_m - r) / 200.0 for s, r in zip(scans, rb, strict=False) if s.plots]
    assert len(z) == len(tr) and max(abs(x) for x in z) < 5.0 and np.mean(np.square(z)) == pytest.approx(1, abs=0.4)


def test_pcl_tracker_on_the_recorded_track_beats_a_single_plot_fix() -> None:
    from services.pcl_tracker import mc

    sc = scenario("pcl_tracker_recorded_track", lambda d: sim_params(d)["targets"].pop(1))
    params = sc.estimators[0].params
    runs = [mc.run_core(scenario_events(sc, seed=s), params, sc) for s in (1, 2)]
    agg = mc.aggregate(runs)
    err = np.array([np.nan if e is None else e for e in agg["pos_rmse_m"]], dtype=np.float64)
    t = np.array(agg["t_s"])
    late = (t >= 150.0) & (t <= 300.0) & np.isfinite(err)
    # a single plot fixes the target no better than sqrt((sigma_rb / 2)^2 + (R sigma_az)^2 + (R sigma_el)^2): the
    # bistatic range's gradient is 2 cos(beta / 2) <= 2, and R is at least the track's nearest slant range in the
    # second half (10 km; 0.5 deg each): 159 m; a tracker that holds the track does better
    single = math.sqrt(100.0**2 + 2 * (10_000.0 * math.radians(0.5)) ** 2)
    assert late.sum() > 40
    assert float(np.sqrt(np.mean(err[late] ** 2))) < single
    assert agg["coverage"] > 0.9


def test_pcl_track_excludes_the_synthetic_motion() -> None:
    track = {"path": str(TRACKS / "adsb_turn.csv"), "time_column": "time"}
    PclSimParams.model_validate({"targets": [{"id": "a", "track": track}]})
    for extra in ({"position_m": [0, 0, 0]}, {"speed_mps": 100.0}, {"birth_s": 3.0}, {"turn_rate_dps": 1.0}):
        with pytest.raises(ValidationError, match="track replaces the target's motion"):
            PclSimParams.model_validate({"targets": [{"id": "a", "track": track, **extra}]})
    with pytest.raises(ValidationError, match="position_m"):
        PclSimParams.model_validate({"targets": [{"id": "a", "speed_mps": 100.0}]})


# ----- rd_group ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rd_events() -> list[Event]:
    def longer(doc: dict[str, Any]) -> None:
        doc["duration_s"] = 700

    return scenario_events(scenario("rd_recorded_track", longer), seed=6)


def test_rd_mover_truth_is_the_recorded_log_and_the_run_ends_with_it(rd_events: list[Event]) -> None:
    r = rows("auv_rd_stop.csv")
    t_rows = r["t_s"]
    rec = np.column_stack([r["east_m"], r["north_m"], r["up_m"]])
    tr = truths(rd_events, "auv4")
    t = np.array([m.header.stamp_ns / NS for m in tr])
    pos = np.array([m.position_m for m in tr])
    on_rows = np.isin(np.round(t, 9), t_rows)
    assert on_rows.sum() >= 60  # the periodic truth every 10 s
    np.testing.assert_allclose(pos[on_rows], rec[np.searchsorted(t_rows, t[on_rows])], atol=EXACT_M, rtol=0)
    # between rows (truth at the leader arrivals): on the documented method for smoothing none, the natural cubic
    # spline through the rows (scipy's, per axis), and within 0.1 m of the rows' chords (sagitta of a 3 m chord
    # in the 57 m-radius turn: 0.02 m; the spline's overshoot at the speed ramps: a few cm)
    between = ~on_rows
    spline = CubicSpline(t_rows, rec, bc_type="natural")
    assert between.sum() > 40
    np.testing.assert_allclose(pos[between], spline(t[between]), atol=EXACT_M, rtol=0)
    lin = np.column_stack([np.interp(t[between], t_rows, rec[:, k]) for k in range(3)])
    assert np.max(np.abs(pos[between] - lin)) < 0.1
    # the run (scenario: 700 s) ends with the track at 600 s
    assert max(ev.stamp_ns for ev in rd_events) <= 600 * NS + NS // 2
    assert t[-1] == pytest.approx(600.0, abs=0.5)


def test_rd_mover_sensors_agree_with_the_recorded_log(rd_events: list[Event]) -> None:
    r = rows("auv_rd_stop.csv")
    depth = [ev.msg.depth_m for ev in rd_events if isinstance(ev.msg, Depth) and "/auv4/" in ev.key]
    sigma_depth = ScenarioConfig().depth_sigma_m  # the REF preset's depth noise
    assert len(depth) == 61  # every depth_period_s = 10 s from t = 0 to the end of the log
    assert np.max(np.abs(np.array(depth) - 80.0)) <= 5 * sigma_depth + 1e-9
    # DVL speed = the log's horizontal speed (differences of the 2 s rows: the spline's speed at the midpoints
    # to O(dt^2)) + the §5.4 speed errors (Gauss-Markov 0.02 m/s + white 0.01 m/s: 5 sigma = 0.12 m/s)
    speed_rows = np.hypot(np.diff(r["east_m"]), np.diff(r["north_m"])) / np.diff(r["t_s"])
    mid = 0.5 * (r["t_s"][1:] + r["t_s"][:-1])
    dvl = [(ev.stamp_ns / NS, ev.msg.v_forward_mps) for ev in rd_events if isinstance(ev.msg, SpeedLog)]
    td, vd = np.array(dvl).T
    err = vd - np.interp(td, mid, speed_rows)
    assert td.size > 500 and np.max(np.abs(err)) < 0.12 + 0.02  # + the chord error near the ramps
    stopped = (td > 212) & (td < 268)
    assert np.max(np.abs(vd[stopped])) < 0.12


def test_rd_estimator_on_the_recorded_log_is_consistent() -> None:
    from services.rd_nav import mc

    sc = scenario("rd_recorded_track")
    params = sc.estimators[0].params
    runs = [mc.run_core(scenario_events(sc, seed=s), params, sc) for s in (1, 2)]
    for run in runs:
        ekf = run["ekf_summary"]
        assert ekf["n"] >= 50
        # NEES of the 2-D fix: chi2(2) has mean 2; ~55 fixes per run, correlated: the run mean below 4
        assert ekf["mean_nees"] < 4.0
        # the digest's simulation figure (ref. [28]): every fix within 2 m
        assert ekf["max_m"] < 2.0


def test_rd_track_excludes_paths_and_docking() -> None:
    track = {"path": str(TRACKS / "auv_rd_stop.csv")}
    ok = {"preset": "custom", "nodes": {"n1": [0, 0, 100], "n2": [0, 3000, 100]}}
    vehicles = [{"id": "auv1", "node": "n1"}, {"id": "auv2", "node": "n2"}]
    RdGroupParams.model_validate({**ok, "vehicles": [*vehicles, {"id": "auv4", "track": track}]})
    for extra in ({"path": "inside"}, {"node": "n1"}, {"route": ["n1"]}, {"repeat": True}):
        with pytest.raises(ValidationError):
            RdGroupParams.model_validate({**ok, "vehicles": [*vehicles, {"id": "auv4", "track": track, **extra}]})
    late = {**track, "time_offset_s": 5.0}
    with pytest.raises(ValidationError, match="from t = 0"):
        RdGroupParams.model_validate({**ok, "vehicles": [*vehicles, {"id": "auv4", "track": late}]})


def test_a_geodetic_track_shows_on_the_map_where_it_was_recorded() -> None:
    """Player -> Truth -> the Foxglove map channel of the scenario (whose origin is the track's): latitude,
    longitude and height are the track file's rows. With the flat-earth arcs the map used before, the aircraft
    39 km out at 5 km drew ~120 m low and tens of metres off."""
    sc = scenario("attitude_recorded_track", _exact_adsb)
    assert sc.origin is not None and (sc.origin.lat_deg, sc.origin.lon_deg) == (45.0, 7.0)
    conv = Converter.for_scenario(sc)
    r = rows("adsb_turn.csv")
    t_rows, _ = adsb_enu()
    fixes = []
    for ev in scenario_events(sc, seed=4):
        if isinstance(ev.msg, Truth) and ev.msg.platform == "adsb1":
            (fix,) = [c.message for c in conv.convert(ev.key, ev.msg) if c.topic.startswith("/foxglove/location/")]
            schema = type(fix).get_schema()
            decoded = proto_class(schema.name, schema.data).FromString(fix.encode())  # the bytes a viewer reads
            fixes.append((ev.msg.header.stamp_ns / NS, decoded))
    assert len(fixes) == 61
    i = np.searchsorted(t_rows, [t for t, _ in fixes])
    got = np.array([[f.latitude, f.longitude, f.altitude] for _, f in fixes])
    # smoothing none: the truth is the rows exactly; 1e-9 deg is 0.1 mm
    np.testing.assert_allclose(got[:, :2], np.column_stack([r["lat_deg"][i], r["lon_deg"][i]]), atol=1e-9, rtol=0)
    np.testing.assert_allclose(got[:, 2], r["alt_m"][i], atol=1e-4, rtol=0)
