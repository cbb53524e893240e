"""The Gaussian estimate block (issue 19, item 6): its schema checks, the builder and the generic conversion.

The conversion is checked against the frame table of ``shared/foxglove/frames.py``'s module doc written out
here as explicit maps (east, north, up from the frame's axes), on blocks whose components come in any order.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from schemas import Header
from schemas.estimate import CV_STATE, HORIZONTAL, POSITION, GaussianEstimate, Layout
from schemas.rd_nav import RdNavFix
from schemas.terrain_nav import MAP_HORIZONTAL
from shared.estimates import gaussian
from shared.foxglove.frames import NOMINAL_VERTICAL_VAR_M2, FrameContext, gaussian_position

SITE = [1000.0, -2000.0, 30.0]
CTX = FrameContext(sites={"r1": SITE})

#: frame -> (axis names in the frame's order, ENU from the frame's (a, b, c) values): the module doc's table
FRAMES = {
    "pcl_enu": (("x", "y", "z"), lambda a, b, c: [a, b, c]),
    "base_ned": (("x", "y", "z"), lambda a, b, c: [b, a, -c]),
    "local_en_depth": (("x", "y", "z"), lambda a, b, c: [a, b, -c]),
    "map": (("x", "z", "h"), lambda a, b, c: [b, a, c]),
    "radar_nue/r1": (("x", "y", "z"), lambda a, b, c: [c + SITE[0], a + SITE[1], b + SITE[2]]),
}

finite = st.floats(-1e6, 1e6, allow_nan=False)


def _spd(n: int, seed: int) -> list[list[float]]:
    a = np.random.default_rng(seed).normal(size=(n, n))
    return (a @ a.T + n * np.eye(n)).tolist()  # type: ignore[no-any-return]


def _enu_cov(frame: str, c: np.ndarray) -> np.ndarray:
    """The 3x3 frame-order covariance ``c`` in ENU axes by the same maps (linear part: differences of means)."""
    f = FRAMES[frame][1]
    base = np.array(f(0.0, 0.0, 0.0))
    t = np.column_stack([np.array(f(*e)) - base for e in np.eye(3)])  # column k: ENU image of axis k
    return t @ c @ t.T  # type: ignore[no-any-return]


@settings(max_examples=60)
@given(frame=st.sampled_from(sorted(FRAMES)), mean=st.lists(finite, min_size=5, max_size=5), seed=st.integers(0, 99))
def test_a_3d_block_in_any_component_order_converts_by_the_frame_table(
    frame: str, mean: list[float], seed: int
) -> None:
    names, to_enu = FRAMES[frame]
    comps = [names[2], "v1", names[0], "v2", names[1]]  # positions found by name, wherever they are
    cov = _spd(5, seed)
    est = GaussianEstimate(frame=frame, components=comps, units=["m"] * 5, mean=mean, covariance=cov)
    got = gaussian_position(est, CTX)
    assert got is not None
    pos, pcov, horizontal = got
    a, b, c = mean[2], mean[4], mean[0]
    assert not horizontal
    np.testing.assert_allclose(pos, to_enu(a, b, c), rtol=1e-12, atol=1e-9)
    sub = np.array(cov)[np.ix_([2, 4, 0], [2, 4, 0])]
    np.testing.assert_allclose(pcov, _enu_cov(frame, sub), rtol=1e-12)


@settings(max_examples=40)
@given(frame=st.sampled_from(["base_ned", "local_en_depth", "map", "pcl_enu"]), seed=st.integers(0, 99))
def test_a_horizontal_block_is_placed_at_the_given_vertical(frame: str, seed: int) -> None:
    names, to_enu = FRAMES[frame]
    cov = _spd(2, seed)
    est = GaussianEstimate(
        frame=frame, components=[names[0], names[1]], units=["m", "m"], mean=[3.0, 4.0], covariance=cov
    )
    pos, pcov, horizontal = gaussian_position(est, CTX, vertical=(7.0, 2.5)) or (None, None, None)
    assert horizontal and pos is not None and pcov is not None
    np.testing.assert_allclose(pos, to_enu(3.0, 4.0, 7.0))
    want = _enu_cov(frame, np.array([[cov[0][0], cov[0][1], 0.0], [cov[1][0], cov[1][1], 0.0], [0.0, 0.0, 2.5]]))
    np.testing.assert_array_equal(pcov, want + 0.0)  # exact: taken by index, no signed zeros
    default = gaussian_position(est, CTX)
    assert default is not None and default[1][2, 2] == NOMINAL_VERTICAL_VAR_M2


def test_a_block_without_position_components_has_no_position() -> None:
    vertical = GaussianEstimate(frame="map", components=["dvh", "dh"], units=["m/s", "m"], mean=[0.1, -3.0],
                                covariance=[[1.0, 0.0], [0.0, 4.0]])  # fmt: skip
    bistatic = gaussian("bistatic/rx1/fm", Layout(("r_b", "az"), ("m", "deg")), [1.0, 2.0], [[1.0, 0.0], [0.0, 1.0]])
    assert gaussian_position(vertical, CTX) is None and gaussian_position(bistatic, CTX) is None


def test_the_block_refuses_mismatched_lengths_and_a_covariance_that_is_not_psd() -> None:
    ok = {"frame": "map", "components": ["x", "z"], "units": ["m", "m"], "mean": [1.0, 2.0]}
    with pytest.raises(ValidationError, match="one entry"):
        GaussianEstimate(**ok, covariance=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    with pytest.raises(ValidationError, match="one entry"):
        GaussianEstimate(**{**ok, "units": ["m"]}, covariance=[[1.0, 0.0], [0.0, 1.0]])
    with pytest.raises(ValidationError, match="positive semi-definite"):
        GaussianEstimate(**ok, covariance=[[1.0, 2.0], [2.0, 1.0]])


def test_a_message_refuses_a_block_of_another_layout() -> None:
    def fix(est: GaussianEstimate) -> RdNavFix:
        return RdNavFix(header=Header(stamp_ns=1), auv_id="a", estimator="PF", kind="CYCLE", estimate=est, depth_m=5.0,
                        status="TRACKING", valid=True, cycle_status="USED", n_eff=1.0, n_particles=1, reinit_count=0,
                        cycles_since_update=0)  # fmt: skip

    cov = [[1.0, 0.0], [0.0, 1.0]]
    assert fix(gaussian("base_ned", HORIZONTAL, [1.0, 2.0], cov)).estimate.mean == [1.0, 2.0]
    for bad in (MAP_HORIZONTAL, Layout(("y", "x"), ("m", "m")), Layout(("x", "y"), ("m", "ft"))):
        with pytest.raises(ValidationError, match="estimate: components"):
            fix(gaussian("base_ned", bad, [1.0, 2.0], cov))
    with pytest.raises(ValidationError, match="estimate: components"):
        fix(gaussian("base_ned", POSITION, [1.0, 2.0, 3.0], np.eye(3).tolist()))


@settings(max_examples=30)
@given(mean=st.lists(finite, min_size=6, max_size=6), seed=st.integers(0, 99))
def test_an_unvalidated_block_is_the_validated_one(mean: list[float], seed: int) -> None:
    cov = _spd(6, seed)
    a = gaussian("pcl_enu", CV_STATE, mean, cov)
    b = gaussian("pcl_enu", CV_STATE, mean, cov, validate=False)
    assert a == b and a.model_dump() == b.model_dump() and b.model_fields_set == a.model_fields_set
    assert GaussianEstimate.model_validate(b.model_dump()) == a


def test_the_fieldmap_table_turns_an_old_layout_message_into_the_new_one() -> None:
    """bench/outputs_fieldmap.py's table on hand-written messages of the old layout (base 6889e57's fields)."""
    from samples_pcl_tracker import EXAMPLES as PCL
    from samples_rd_nav import EXAMPLES as RD

    spec = importlib.util.spec_from_file_location(
        "outputs_fieldmap", Path(__file__).parents[1] / "bench/outputs_fieldmap.py"
    )
    assert spec is not None and spec.loader is not None
    fieldmap = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fieldmap)
    to_new_layout = fieldmap.to_new_layout
    from shared import codec

    rd = codec.unpack(codec.encode(RD["RdNavFix"]))
    old = {k: v for k, v in rd.items() if k not in ("estimate", "depth_m")}
    old.update(position_ned_m=[*rd["estimate"]["mean"], rd["depth_m"]], cov_xy_m2=rd["estimate"]["covariance"])
    assert to_new_layout("RdNavFix", old) and old == rd
    assert not to_new_layout("RdNavFix", rd)  # the new layout is left alone

    scan = codec.unpack(codec.encode(PCL["PclScanReport"]))
    old_scan = {**scan, "tracks": []}
    for t in scan["tracks"]:
        e, b = t["estimate"], t["bistatic"]
        rest = {k: v for k, v in t.items() if k not in ("estimate", "bistatic")}
        old_scan["tracks"].append(
            {
                **rest,
                "state_enu": e["mean"],
                "cov_enu": e["covariance"],
                "bistatic": b["mean"],
                "bistatic_cov": b["covariance"],
            }
        )
    assert to_new_layout("PclScanReport", old_scan) and old_scan == scan


def test_a_message_type_without_a_view_is_converted_through_its_block() -> None:
    from schemas import Message
    from shared.foxglove.frames import estimates_of

    class _Sounding(Message):  # a leading underscore: not registered among the wire models
        estimate: GaussianEstimate
        valid: bool = True

    cov = [[4.0, 1.0], [1.0, 9.0]]
    msg = _Sounding(header=Header(stamp_ns=5), estimate=gaussian("base_ned", HORIZONTAL, [10.0, 20.0], cov))
    (e,) = estimates_of("fixstream/fix/sonar/auv7", msg, CTX)
    assert (e.kind, e.entity, e.stamp_ns, e.valid, e.horizontal_only) == ("fix", "auv7", 5, True, True)
    np.testing.assert_array_equal(e.position, [20.0, 10.0, 0.0])  # NED x north, y east -> east, north
    assert e.cov is not None and e.cov[:2, :2].tolist() == [[9.0, 1.0], [1.0, 4.0]]
    invalid = msg.model_copy(update={"valid": False})
    assert not estimates_of("fixstream/fix/sonar/auv7", invalid, CTX)[0].valid
