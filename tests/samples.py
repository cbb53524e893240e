"""One valid example of every message model, built independently of the codec under test."""

from __future__ import annotations

from schemas import (
    MODELS,
    AcousticArrival,
    Attitude,
    BaroAltitude,
    Beacon,
    BeaconRange,
    BeaconTable,
    BistaticConfigUpdate,
    BistaticPlot,
    BistaticScan,
    Current,
    Depth,
    Diagnostic,
    Fix,
    Header,
    Heading,
    Hypothesis,
    InsSample,
    Message,
    NavPacket,
    NavReset,
    RadarPlot,
    RadarSite,
    RadioAltimeter,
    ScenarioMarker,
    SoundSpeed,
    SpeedLog,
    Track,
    TrackEnd,
    Truth,
)
from schemas.estimate import GaussianEstimate

H = Header(stamp_ns=1_700_000_000_123_456_789, frame_id="local_enu", source="test/1", seq=42)
COV3 = [[4.0, 0.5, 0.0], [0.5, 9.0, 0.0], [0.0, 0.0, 0.25]]
COV6 = [[float(i == j) * (1.0 + i) for j in range(6)] for i in range(6)]
POS3 = GaussianEstimate(
    frame="local_enu", components=["x", "y", "z"], units=["m", "m", "m"], mean=[10.0, 20.0, 30.0], covariance=COV3
)
STATE6 = GaussianEstimate(
    frame="local_enu",
    components=["x", "y", "z", "vx", "vy", "vz"],
    units=["m", "m", "m", "m/s", "m/s", "m/s"],
    mean=[1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
    covariance=COV6,
)
PACKET = NavPacket(
    sender_id="auv2",
    kind="FOLLOWER",
    leader_id="auv1",
    cycle_seq=7,
    assignment_epoch=3,
    node_id="n4",
    pos_ned_m=[100.0, -20.5, 48.0],
    pos_sigma_m=0.5,
    reply_delay_s=1.25,
    state_flags=1,
)

EXAMPLES: dict[str, Message] = {
    "SpeedLog": SpeedLog(header=H, v_forward_mps=1.5, v_starboard_mps=-0.1, avg_interval_s=1.0),
    "Heading": Heading(header=H, heading_rad=1.2),
    "Attitude": Attitude(header=H, heading_rad=3.0, pitch_rad=0.05, roll_rad=-0.02),
    "Depth": Depth(header=H, depth_m=35.5),
    "Current": Current(header=H, u_north_mps=0.1, u_east_mps=-0.2),
    "SoundSpeed": SoundSpeed(header=H, c_mps=1498.2, sigma_c_mps=0.5, model="Mackenzie1981"),
    "InsSample": InsSample(header=H, x_m=1000.0, z_m=-250.0, h_m=900.0, vx_mps=200.0, vz_mps=1.0, vh_mps=0.0),
    "RadioAltimeter": RadioAltimeter(header=H, h_agl_m=512.25, valid=True),
    "BaroAltitude": BaroAltitude(header=H, h_baro_m=903.0),
    "NavReset": NavReset(header=H, reason="operator"),
    "BeaconTable": BeaconTable(header=H, beacons=[Beacon(beacon_id="b1", x_east_m=0.0, y_north_m=0.0, depth_m=100.0)]),
    "BeaconRange": BeaconRange(header=H, beacon_id="b1", range_m=812.5, quality=0.9),
    "AcousticArrival": AcousticArrival(header=H, receiver_id="auv5", t_rx_local_s=1234.5678, packet=PACKET),
    "RadarSite": RadarSite(
        header=H,
        site_id="r1",
        lat_deg=55.7,
        lon_deg=37.6,
        h_m=150.0,
        sigma_r_m=50.0,
        sigma_az_deg=0.2,
        sigma_el_deg=0.3,
        scan_period_s=5.0,
    ),
    "RadarPlot": RadarPlot(header=H, site_id="r1", target_id="t17", range_m=100_000.0, az_deg=60.0, el_deg=2.8),
    "TrackEnd": TrackEnd(header=H, site_id="r1", target_id="t17"),
    "BistaticScan": BistaticScan(
        header=H,
        receiver_id="rx1",
        illuminator_id="fm98",
        scan_id=12,
        plots=[
            BistaticPlot(
                plot_id="p1",
                azimuth_deg=45.0,
                elevation_deg=3.0,
                bistatic_range_m=25_000.0,
                bistatic_velocity_mps=-120.0,
                sigma_rb_m=200.0,
            ),
            BistaticPlot(plot_id="p2", azimuth_deg=-170.0, elevation_deg=1.0, delay_s=1e-4, doppler_hz=12.5),
        ],
    ),
    "BistaticConfigUpdate": BistaticConfigUpdate(
        header=H,
        receiver_id="rx1",
        illuminator_id="fm98",
        tx_position_enu_m=[8000.0, 0.0, 300.0],
        wavelength_m=3.06,
    ),
    "Truth": Truth(
        header=H,
        platform="auv1",
        position_m=[1.0, 2.0, 3.0],
        velocity_mps=[0.5, 0.0, 0.0],
        attitude_rad=[0.1, 0.0, 0.0],
        extra={"dK_rad": 0.01},
    ),
    "ScenarioMarker": ScenarioMarker(
        header=H, event="end", scenario="demo", seed=7, published={"fixstream/truth/auv1": 10}
    ),
    "Fix": Fix(
        header=H,
        platform="auv1",
        estimator="lbl",
        status="RESOLVED",
        valid=True,
        estimate=POS3,
        hypotheses=[Hypothesis(hypothesis_id=1, estimate=POS3, probability=0.99)],
    ),
    "Track": Track(
        header=H,
        tracker="pcl",
        track_id=3,
        status="CONFIRMED",
        estimate=STATE6,
    ),
    "Diagnostic": Diagnostic(
        header=H,
        service="recorder",
        instance="main",
        key="fixstream/sensor/a/b/c",
        reason="non_finite",
        detail="x",
        count=3,
        counts={"non_finite": 3},
    ),
}


def available_examples() -> dict[str, Message]:
    """EXAMPLES here plus ``EXAMPLES`` of every ``tests/samples_<topic>.py`` (one per estimator)."""
    import importlib
    import pkgutil
    from pathlib import Path

    merged = dict(EXAMPLES)
    for info in pkgutil.iter_modules([str(Path(__file__).parent)]):
        if info.name.startswith("samples_"):
            merged.update(importlib.import_module(info.name).EXAMPLES)
    return merged


def all_examples() -> dict[str, Message]:
    """Every model's example; fails if a registered model has none (the contract tests need all)."""
    merged = available_examples()
    missing = set(MODELS) - set(merged)
    assert not missing, f"tests/samples*.py have no example for {sorted(missing)}"
    return merged
