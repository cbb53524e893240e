"""The Foxglove channels (issue 8): the recorder's scene and map channels read back and checked.

* End to end: the demo scenario, shortened and given a geodetic ``origin``, through the repository's compose
  stack (``fixstream up``) with ``FIXSTREAM_RECORDER_FOXGLOVE=true``. Every record on a ``/foxglove/...`` channel
  has Foxglove's own schema (``foxglove.SceneUpdate`` / ``LocationFix`` / ``LocationFixes``: the schema data is
  the foxglove-sdk's FileDescriptorSet byte for byte), decodes with the ``protobuf`` package against that
  schema and re-encodes to the same bytes (no unknown or malformed field). Each scene entity matches the
  fixstream message it came from, recomputed here independently of ``shared/foxglove``: its position in the
  scenario's ENU frame, and its covariance rebuilt from the ellipsoid (rotation from the quaternion, variances
  from the 3σ diameters) equal to the message's covariance in ENU axes. Each map fix is at the right great-circle
  distance and bearing from the origin, its altitude the origin's plus "up". The fixstream channels are the same
  as without the Foxglove channels (every one decodes; one channel per key).
* Units: ellipsoid axes of known covariances, the quaternion of known rotations, the geodetic conversion.
* LBL and group navigation (from their cores): both hypotheses are entities while the launch is ambiguous;
  group fixes carry their 2-D covariance and a nominal vertical axis.
"""

from __future__ import annotations

import math
import os
import subprocess
from collections import Counter, defaultdict
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import yaml
from conftest import REPO, fixstream_cmd
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from samples import EXAMPLES
from test_recorded_track import enu_independent

from schemas import Message, ScenarioMarker, Truth
from schemas.attitude import AttitudeEstimate
from schemas.lbl_nav import LblFix
from schemas.pcl_tracker import PclScanReport
from schemas.rd_nav import RdNavFix
from schemas.terrain_nav import TerrainFix
from shared.foxglove.convert import N_SIGMA, POINT_SIZE_M, Converter, Origin, ellipsoid, quaternion
from shared.foxglove.frames import NOMINAL_VERTICAL_VAR_M2, FrameContext
from shared.foxglove.recording import FoxgloveChannels
from shared.mcap_io import decode_record, iter_records, recording_files
from tools.report.offline import lbl_items, rd_items, write_recording

ORIGIN = {"lat_deg": 43.05, "lon_deg": 131.88, "alt_m": 12.0}


# ----- independent references ---------------------------------------------------------------------------------


def quat_to_matrix(q: Any) -> np.ndarray:
    x, y, z, w = q.x, q.y, q.z, q.w
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def cov_of_sphere(sphere: Any) -> np.ndarray:
    rot = quat_to_matrix(sphere.pose.orientation)
    sig = np.array([sphere.size.x, sphere.size.y, sphere.size.z]) / (2.0 * N_SIGMA)
    return np.asarray(rot @ np.diag(sig**2) @ rot.T)


def expected(msg: Message, site_enu: dict[str, list[float]]) -> list[tuple[str, np.ndarray, np.ndarray | None]]:
    """(entity id, ENU position, ENU covariance or None) a message should become, computed from its fields."""
    if isinstance(msg, Truth):
        return [(msg.platform, np.array(msg.position_m), None)]
    if isinstance(msg, TerrainFix):
        cxz = np.array(msg.estimate.covariance)  # (x north, z east)
        var_dh = msg.vertical.covariance[1][1]  # (dvh, dh)
        cov = np.array([[cxz[1, 1], cxz[1, 0], 0.0], [cxz[0, 1], cxz[0, 0], 0.0], [0.0, 0.0, var_dh]])
        x_corr, z_corr = msg.estimate.mean
        return [("tan1", np.array([z_corr, x_corr, msg.h_corr_m]), cov)]
    if isinstance(msg, PclScanReport):
        return [
            (f"track {t.track_id}", np.array(t.estimate.mean[:3]), np.array(t.estimate.covariance)[:3, :3])
            for t in msg.tracks
            if t.status != "DROPPED"
        ]
    if isinstance(msg, AttitudeEstimate) and msg.estimate is not None:
        x = msg.estimate.mean  # [x north, vx, ax, y up, vy, ay, z east, vz, az]
        pos = np.array([x[6], x[0], x[3]]) + np.array(site_enu[msg.site_id])
        p = np.array(msg.estimate.covariance)
        idx = [6, 0, 3]  # east, north, up
        return [(msg.target_id, pos, p[np.ix_(idx, idx)])]
    return []


def proto_class(schema_name: str, data: bytes) -> Any:
    fds = descriptor_pb2.FileDescriptorSet.FromString(data)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def foxglove_records(path: Path) -> list[tuple[str, str, int, Any]]:
    """(topic, schema name, publish time, decoded protobuf) of every Foxglove record; checks schema and bytes."""
    from foxglove import messages as fm

    out = []
    classes: dict[int, Any] = {}
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if schema is None or not schema.name.startswith("foxglove."):
                continue
            assert channel.message_encoding == "protobuf" and schema.encoding == "protobuf"
            official = getattr(fm, schema.name.removeprefix("foxglove.")).get_schema()
            assert schema.data == bytes(official.data), f"{schema.name}: not Foxglove's own schema"
            if schema.id not in classes:
                classes[schema.id] = proto_class(schema.name, schema.data)
            decoded = classes[schema.id].FromString(message.data)
            assert decoded.SerializeToString(deterministic=True) == message.data, channel.topic
            out.append((channel.topic, schema.name, message.publish_time, decoded))
    return out


# ----- end to end -----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def stack_recording(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    tmp = tmp_path_factory.mktemp("foxglove")
    doc = yaml.safe_load((REPO / "scenarios" / "demo.yaml").read_text())
    doc.update(name="demo_foxglove", duration_s=24.0, origin=ORIGIN)
    for sim in doc["simulators"]:
        if sim["kind"] == "nav_platform":
            sim["params"]["legs"] = [{"duration_s": 12.0}, {"duration_s": 12.0, "turn_rate_dps": 6.0}]
        if sim["kind"] == "terrain_nav":
            sim["params"]["failures"] = []
            sim["params"]["nan_samples"] = 0  # (NaN samples do not validate: the recorder refuses them)
    scenarios = tmp / "scenarios"
    scenarios.mkdir()
    (scenarios / "demo_foxglove.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    env = {k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_")}
    env.update(
        {
            "FIXSTREAM_SCENARIO": str(scenarios / "demo_foxglove.yaml"),
            "FIXSTREAM_RATE": "0",
            "FIXSTREAM_RECORDER_FOXGLOVE": "true",
            "FIXSTREAM_RECORDER_SCENARIOS_DIR": str(scenarios),
        }
    )
    done = subprocess.run(
        fixstream_cmd("up", "-f", str(REPO / "compose.yaml"), "--recordings", str(tmp / "rec"), "--no-color"),
        cwd=tmp,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, (done.stdout + done.stderr)[-5000:]
    (path,) = recording_files(tmp / "rec")
    sites = {
        s["params"]["site_id"]: s["params"].get("site_position_m", [0.0, 0.0, 0.0])
        for s in doc["simulators"]
        if s["kind"] == "attitude"
    }
    return {"path": path, "sites": sites, "log": done.stdout}


def test_fixstream_channels_are_unchanged(stack_recording: dict[str, Any]) -> None:
    counts: Counter[str] = Counter()
    end = None
    for rec in iter_records(stack_recording["path"]):
        if rec.schema_name.startswith("fixstream."):
            msg = decode_record(rec)  # every fixstream record still decodes
            assert rec.topic.startswith("fixstream/")
            counts[rec.topic] += 1
            if isinstance(msg, ScenarioMarker) and msg.event == "end":
                end = msg
        else:
            assert rec.topic.startswith("/foxglove/") and rec.schema_name.startswith("foxglove."), rec.topic
    assert end is not None and sum(end.published.values()) > 1000
    for key, n in end.published.items():  # everything the player published is there, once
        assert counts[key] == n, key


def test_scene_and_map_channels_validate_and_match_their_fixes(stack_recording: dict[str, Any]) -> None:
    path = stack_recording["path"]
    fox = foxglove_records(path)
    kinds = Counter(name for _, name, _, _ in fox)
    assert kinds["foxglove.SceneUpdate"] > 100 and kinds["foxglove.LocationFix"] > 100
    assert kinds["foxglove.LocationFixes"] > 0
    # index the Foxglove messages by (topic, stamp)
    scenes: dict[tuple[str, int], list[Any]] = defaultdict(list)
    locs: dict[tuple[str, int], list[Any]] = defaultdict(list)
    for topic, name, stamp, m in fox:
        key = topic.split("/", 3)[3]
        (scenes if name == "foxglove.SceneUpdate" else locs)[(key, stamp)].append(m)
    origin = Origin(**{"lat_deg": ORIGIN["lat_deg"], "lon_deg": ORIGIN["lon_deg"], "alt_m": ORIGIN["alt_m"]})
    checked: Counter[str] = Counter()
    for rec in iter_records(path):
        if not rec.schema_name.startswith("fixstream."):
            continue
        msg = decode_record(rec)
        want = expected(msg, stack_recording["sites"])
        if not want:
            continue
        key = (rec.topic.removeprefix("fixstream/"), msg.header.stamp_ns)
        (update,) = scenes[key]
        entities = {e.id: e for e in update.entities}
        assert set(entities) == {w[0] for w in want}, key
        for ent_id, pos, cov in want:
            e = entities[ent_id]
            assert e.frame_id == "local_enu"
            (sphere,) = e.spheres
            p = sphere.pose.position
            assert np.allclose([p.x, p.y, p.z], pos, rtol=0, atol=1e-6), (key, ent_id)
            if cov is None:
                assert (sphere.size.x, sphere.size.y, sphere.size.z) == (POINT_SIZE_M,) * 3
            else:
                scale = max(1.0, float(np.abs(cov).max()))
                assert np.allclose(cov_of_sphere(sphere), cov, rtol=0, atol=1e-6 * scale), (key, ent_id)
        fixes = [f for m in locs.get(key, []) for f in (m.fixes if hasattr(m, "fixes") else [m])]
        assert len(fixes) == len(want), key
        for (ent_id, pos, _), fix in zip(want, fixes, strict=True):
            # the map fix is the ENU position on WGS84: back through closed-form geodesy, it is the position
            lla = (np.array([fix.latitude]), np.array([fix.longitude]), np.array([fix.altitude]))
            enu = enu_independent(*lla, origin)[0]  # type: ignore[arg-type]
            assert np.allclose(enu, pos, rtol=0.0, atol=GEODESY_ATOL_M), (key, ent_id)
        checked[type(msg).__name__] += 1
    assert set(checked) == {"Truth", "TerrainFix", "PclScanReport", "AttitudeEstimate"}, checked
    assert min(checked.values()) >= 3


# ----- units ----------------------------------------------------------------------------------------------------


def sphere_of(size: list[float], q: list[float]) -> SimpleNamespace:
    """The fields of a SpherePrimitive that :func:`cov_of_sphere` reads."""
    return SimpleNamespace(
        pose=SimpleNamespace(orientation=SimpleNamespace(x=q[0], y=q[1], z=q[2], w=q[3])),
        size=SimpleNamespace(x=size[0], y=size[1], z=size[2]),
    )


def test_ellipsoid_of_known_covariances() -> None:
    size, q = ellipsoid(np.diag([4.0, 9.0, 1.0]))
    assert sorted(size) == pytest.approx(sorted([6 * 2.0, 6 * 3.0, 6 * 1.0]))
    rot = np.array([[math.cos(0.7), -math.sin(0.7), 0.0], [math.sin(0.7), math.cos(0.7), 0.0], [0.0, 0.0, 1.0]])
    cov = rot @ np.diag([100.0, 4.0, 0.25]) @ rot.T
    size, q = ellipsoid(cov)
    assert np.allclose(cov_of_sphere(sphere_of(size, q)), cov, atol=1e-9)
    assert np.linalg.norm(q) == pytest.approx(1.0)
    for angle in (0.0, 2.0, 3.1):
        c, s = math.cos(angle), math.sin(angle)
        m = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
        x, y, z, w = quaternion(m)
        assert np.allclose(quat_to_matrix(SimpleNamespace(x=x, y=y, z=z, w=w)), m, atol=1e-12)


#: metres: PROJ's inverse of the topocentric frame against the closed-form forward transform (worst 8 µm in
#: 2,000 random cases within 200 km), far below anything the stack publishes
GEODESY_ATOL_M = 1e-4


def test_geodetic_origin_is_the_exact_inverse_of_the_tangent_plane() -> None:
    # on the equator the inverse has a closed form: the point is (a + h0 + up) along the origin's radius plus east
    # along the parallel, so lat = 0, lon = lon0 + atan(east / (a + h0 + up)), h = |p| - a
    a_m, east, up = 6378137.0, 111_319.49, 7.0
    lat, lon, alt = Origin(0.0, 10.0, 5.0).to_geodetic([east, 0.0, up])
    assert lat == pytest.approx(0.0, abs=1e-12)
    assert lon == pytest.approx(10.0 + math.degrees(math.atan2(east, a_m + 12.0)), abs=1e-10)
    assert alt == pytest.approx(math.hypot(a_m + 12.0, east) - a_m, abs=GEODESY_ATOL_M)
    # 111 km east of the origin the tangent plane is 971 m above the ellipsoid: no flat-earth arcs
    assert alt - 12.0 == pytest.approx(971.4, abs=0.1)


@settings(max_examples=300, deadline=None)
@given(
    lat0=st.floats(-89.0, 89.0),
    lon0=st.floats(-180.0, 179.999),
    h0=st.floats(-100.0, 5_000.0),
    east=st.floats(-200e3, 200e3),
    north=st.floats(-200e3, 200e3),
    up=st.floats(-5e3, 20e3),
)
def test_geodetic_origin_round_trips_through_closed_form_geodesy(
    lat0: float, lon0: float, h0: float, east: float, north: float, up: float
) -> None:
    """Origin.to_geodetic (PROJ) followed by the textbook geodetic -> ECEF -> tangent-frame transform written in the
    tests returns the ENU point it started from."""
    o = Origin(lat0, lon0, h0)
    lat, lon, alt = o.to_geodetic([east, north, up])
    assert -90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0
    back = enu_independent(np.array([lat]), np.array([lon]), np.array([alt]), o)[0]  # type: ignore[arg-type]
    assert np.allclose(back, [east, north, up], rtol=0.0, atol=GEODESY_ATOL_M)


def test_lbl_hypotheses_and_group_fixes_become_entities(tmp_path: Path) -> None:
    conv = Converter(FrameContext(), Origin(43.0, 131.9))
    channels = FoxgloveChannels(conv)
    lbl, rd = lbl_items(seed=3, t_end_s=40.0), rd_items(seed=2, duration_s=600.0)
    (path,) = write_recording(tmp_path / "rec", lbl, rd, foxglove=channels)
    assert channels.written > 100 and not channels.errors
    fox = foxglove_records(path)
    ambiguous = [f for _, f in lbl if isinstance(f, LblFix) and len(f.hypotheses) == 2 and not f.valid]
    assert ambiguous
    lbl_scenes = [m for t, n, _, m in fox if t == "/foxglove/scene/fix/lbl/auv1" and n == "foxglove.SceneUpdate"]
    two = [m for m in lbl_scenes if {e.id for e in m.entities} == {"auv1/h1", "auv1/h2"}]
    assert len(two) == len(ambiguous)
    rd_fixes = {(f.auv_id, f.header.stamp_ns): f for _, f in rd if isinstance(f, RdNavFix)}
    seen = 0
    for topic, name, stamp, m in fox:
        if name != "foxglove.SceneUpdate" or not topic.startswith("/foxglove/scene/fix/rd/"):
            continue
        (e,) = m.entities
        f = rd_fixes[(e.id, stamp)]
        cxy = np.array(f.estimate.covariance)  # (north, east)
        want = np.array([[cxy[1, 1], cxy[1, 0], 0.0], [cxy[0, 1], cxy[0, 0], 0.0], [0.0, 0.0, NOMINAL_VERTICAL_VAR_M2]])
        assert np.allclose(cov_of_sphere(e.spheres[0]), want, atol=1e-6 * max(1.0, float(np.abs(want).max())))
        p = e.spheres[0].pose.position
        north, east = f.estimate.mean
        assert [p.x, p.y, p.z] == pytest.approx([east, north, -f.depth_m])
        seen += 1
    assert seen == len(rd_fixes)


def test_a_stamp_beyond_foxgloves_time_range_is_a_counted_refusal_with_its_reason() -> None:
    """Header stamps are valid to 2**62 ns; a Foxglove Timestamp holds u32 seconds (to 2**32 s). Past that, the scene
    of a message is not drawn and the loss is counted by its reason (it was an unexplained OverflowError)."""
    from shared.foxglove.convert import FOXGLOVE_MAX_STAMP_NS

    def truth(stamp_ns: int) -> Truth:
        return EXAMPLES["Truth"].model_copy(
            update={"header": EXAMPLES["Truth"].header.model_copy(update={"stamp_ns": stamp_ns})}
        )

    assert Converter().convert("fixstream/truth/p", truth(FOXGLOVE_MAX_STAMP_NS))  # the last representable stamp
    with pytest.raises(ValueError, match="outside Foxglove's time range"):
        Converter().convert("fixstream/truth/p", truth(FOXGLOVE_MAX_STAMP_NS + 1))

    class NoWriter:
        def write_raw(self, *args: Any, **kwargs: Any) -> None:
            raise AssertionError("nothing is written for a message that cannot be converted")

    channels = FoxgloveChannels()
    channels.write(NoWriter(), "fixstream/truth/p", truth(2**62), 0)  # type: ignore[arg-type]
    assert channels.errors == Counter({"Truth: ValueError": 1}) and channels.written == 0
