"""The page an engineer reads in a minute (issue 17, item 9): verdicts against the papers' figures, units, and
plan views that zoom to each track.

* The verdicts: each paper figure's threshold, as the digest states it, decides pass / outside at its boundary
  (the numbers here are the digests': terrain 001 §3.2 "≤ 1 cell"; LBL 000 §3.1 "0 of 1500 wrong", "0–20 m", §3.2
  "4 s / 16 s"; group 002 §5.1 "mean ≤ 0.25 m, SD ≤ 0.75 m, max ≤ 2 m"; PCL 003 §3.3 "< 50 m", "1–2 m/s";
  attitude 004 §3.5 "units of degrees after ~40 contacts");
* the summary says what each figure is in words, never "digest 00x §y";
* metric keys become labels with units;
* a long track far from the rest of the scene gets a panel zoomed to its own extent (not the world's).
"""

from __future__ import annotations

import html
import math
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tools.report.html import label_and_unit, summary_table
from tools.report.paper import NO_DATA, NOT_COMPARABLE, OUTSIDE, PASS, paper_figures, verdicts
from tools.report.plots.common import Section
from tools.report.plots.plan import MIN_HALF_SPAN_M, PAD, plan_axes


def verdict_of(kind: str, headline: dict[str, Any], metrics: dict[str, Any] | None = None) -> list[str]:
    return [v.verdict for v in verdicts(kind, "x", headline, metrics)]


@pytest.mark.parametrize(("worst_cells", "expected"), [(0.0, PASS), (1.0, PASS), (1.01, OUTSIDE), (24.0, OUTSIDE)])
def test_terrain_correction_error_against_one_cell(worst_cells: float, expected: str) -> None:
    metrics = {"max_abs_error_cells": worst_cells, "n_fixes": 5, "n_false_fixes": int(worst_cells > 1)}
    assert verdict_of("terrain_nav", {}, metrics) == [expected]
    assert verdict_of("terrain_nav", {}, None) == [NO_DATA]  # no scenario: no cell size, no verdict
    assert verdict_of("terrain_nav", {}, {"max_abs_error_cells": None, "n_fixes": 0}) == [NO_DATA]


def test_lbl_decision_resolution_time_and_rms() -> None:
    good = {"decision_correct": True, "resolution_after_launch_s": 16.0, "rms_after_resolution_per_axis_m": [20, 3]}
    assert verdict_of("lbl_nav", good) == [PASS, PASS, PASS]
    bad = {"decision_correct": False, "resolution_after_launch_s": 16.5, "rms_after_resolution_per_axis_m": [1, 20.5]}
    assert verdict_of("lbl_nav", bad) == [OUTSIDE, OUTSIDE, OUTSIDE]
    assert verdict_of("lbl_nav", {}) == [NO_DATA, NO_DATA, NO_DATA]


@given(
    st.lists(
        st.tuples(
            st.floats(-1.0, 1.0),
            st.floats(-1.0, 1.0),
            st.floats(0.0, 1.5),
            st.floats(0.0, 1.5),
            st.floats(0.0, 4.0),
        ),
        min_size=1,
        max_size=4,
    )
)
def test_group_errors_pass_only_inside_all_three_bounds(rows: list[tuple[float, float, float, float, float]]) -> None:
    per_auv = {
        f"auv{i}": {"error_mean_m": [me, mn], "error_sd_m": [se, sn], "error_max_abs_m": mx, "cycle_fixes": 9}
        for i, (me, mn, se, sn, mx) in enumerate(rows)
    }
    got = verdicts("rd_nav", "g", {"per_auv": per_auv}, None)
    assert [v.subject for v in got] == sorted(per_auv)
    for v in got:
        me, mn, se, sn, mx = rows[int(v.subject[3:])]
        inside = max(abs(me), abs(mn)) <= 0.25 and max(se, sn) <= 0.75 and mx <= 2.0
        assert v.verdict == (PASS if inside else OUTSIDE), (v, rows)


def test_pcl_position_and_velocity_rmse() -> None:
    assert verdict_of("pcl_tracker", {"pos_rmse_second_half_m": 49.9, "vel_rmse_second_half_mps": 2.0}) == [PASS] * 2
    assert verdict_of("pcl_tracker", {"pos_rmse_second_half_m": 50.0, "vel_rmse_second_half_mps": 2.1}) == [OUTSIDE] * 2


def test_attitude_units_of_degrees_only_from_the_40th_contact() -> None:
    late = {"los_rms_deg_from_scan_40": {"psi_los": 9.9, "theta_los": 1.0, "gamma_los": 3.0}}
    assert verdict_of("attitude", late) == [PASS]
    late["los_rms_deg_from_scan_40"]["gamma_los"] = 10.0
    assert verdict_of("attitude", late) == [OUTSIDE]
    short = {"los_rms_deg_from_scan_15": {"psi_los": 2.0}, "scans_per_target_max": 31}
    (v,) = verdicts("attitude", "r1", short, None)
    assert v.verdict == NOT_COMPARABLE and "31 contacts" in v.note


def test_the_summary_says_what_each_figure_is_in_words() -> None:
    papers = paper_figures()
    assert set(papers) == {"terrain_nav", "lbl_nav", "rd_nav", "pcl_tracker", "attitude"}  # each plugin names its own
    sections = [Section(kind, "i", kind) for kind in papers]
    heads: dict[str, dict[str, Any]] = {
        "lbl_nav": {"decision_correct": True},
        "pcl_tracker": {"pos_rmse_second_half_m": 30.0},
        "rd_nav": {"per_auv": {"auv1": {"error_mean_m": [0.1, 0.1], "error_sd_m": [0.5, 0.5], "error_max_abs_m": 1}}},
    }
    rows = [v for s in sections for v in verdicts(s.kind, s.instance, heads.get(s.kind, {}), None)]
    page = summary_table(sections, rows)
    assert "digest" not in page and "§" not in page  # the figures in words, their source only in metrics.json
    for figure in papers.values():
        for f in figure:
            assert html.escape(f.what) in page and html.escape(f.paper) in page and f.source.startswith("digest 00")
    assert page.count("class='verdict v-pass'") == 3  # LBL decision, PCL position, the AUV


@pytest.mark.parametrize(
    ("key", "label", "unit"),
    [
        ("vel_rmse_second_half_mps", "velocity RMSE second half", "m/s"),
        ("horizontal_error_rms_m", "horizontal error RMS", "m"),
        ("los_rms_deg_from_scan_40", "LOS RMS from scan 40", "°"),
        ("first_fix_s", "first fix", "s"),
        ("max_abs_error_cells", "max abs error", "cells"),
        ("confirmed_tracks", "confirmed tracks", ""),
    ],
)
def test_metric_keys_read_as_labels_with_units(key: str, label: str, unit: str) -> None:
    assert label_and_unit(key)[:2] == (label, unit)


def test_the_nees_share_reads_as_a_percentage() -> None:
    label, unit, scale = label_and_unit("nees_in_95_band")
    assert unit == "%" and scale == 100.0 and "95 %" in label


def _auv_survey(hours: float = 4.0, speed_mps: float = 1.5) -> np.ndarray:
    """A lawn-mower survey (legs of 800 m, 50 m apart) at ``speed_mps`` for ``hours``, 1 sample per second,
    40 km north-east of the origin."""
    n = int(hours * 3600)
    s = np.arange(n) * speed_mps  # distance along the path, m
    period = 2 * (800.0 + 50.0)
    leg, along = np.divmod(s, period)
    x = np.where(along < 800, along, np.where(along < 850, 800.0, np.where(along < 1650, 1650 - along, 0.0)))
    y = leg * 100.0 + np.clip(along - 800, 0, 50) + np.clip(along - 1650, 0, 50)
    return np.column_stack([x + 28_000.0, y + 28_000.0])


def test_a_four_hour_auv_track_gets_a_panel_of_its_own_extent() -> None:
    track = _auv_survey()
    est = track + np.random.default_rng(1).normal(0.0, 2.0, track.shape)
    cov = np.tile(np.diag([4.0, 4.0, 1.0]), (len(est), 1, 1))
    fig, panels, _, _ = plan_axes(
        {"auv1": track}, {"auv1": (est, cov)}, {"receiver": np.zeros((1, 2)), "beacon": np.array([[-5e3, 2e3]])}
    )
    try:
        (overview, none), (zoom, box) = panels
        assert none is None and box is not None
        span = np.ptp(track, axis=0)
        x0, x1 = zoom.get_xlim()
        y0, y1 = zoom.get_ylim()
        assert x0 <= track[:, 0].min() and x1 >= track[:, 0].max()
        assert y0 <= track[:, 1].min() and y1 >= track[:, 1].max()
        # the track fills its panel: at most the padded track on its long side, widened to the panel's shape
        assert max(x1 - x0, y1 - y0) <= 1.6 * max(span) * (1 + 2 * PAD)
        assert overview.get_xlim()[1] - overview.get_xlim()[0] > 20 * (x1 - x0)  # the overview is the world
    finally:
        plt.close(fig)


@settings(max_examples=12, deadline=None)
@given(
    st.floats(-50e3, 50e3),
    st.floats(-50e3, 50e3),
    st.floats(1.0, 5e3),
    st.floats(1.0, 5e3),
    st.integers(2, 300),
    st.integers(0, 2**32 - 1),
)
def test_zoomed_panels_hold_their_track_and_little_else(
    cx: float, cy: float, sx: float, sy: float, n: int, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    track = np.column_stack([cx + sx * rng.random(n), cy + sy * rng.random(n)])
    far = np.array([[cx + 100e3, cy - 100e3]])
    fig, panels, _, _ = plan_axes({"a": track, "b": far + rng.random((2, 2))}, {}, {"radar": far})
    try:
        ax, box = panels[1]  # the overview, then "a"
        assert box is not None
        x0, x1 = ax.get_xlim()
        y0, y1 = ax.get_ylim()
        assert x0 <= track[:, 0].min() and x1 >= track[:, 0].max()
        assert y0 <= track[:, 1].min() and y1 >= track[:, 1].max()
        long_side = max(np.ptp(track, axis=0).max() * (1 + 2 * PAD), 2 * MIN_HALF_SPAN_M)
        assert max(x1 - x0, y1 - y0) <= 1.6 * long_side + 1e-6
        assert math.isfinite(x0) and math.isfinite(y0)
    finally:
        plt.close(fig)
