"""Identity and GOSPA scoring of the PCL tracker (services/pcl_tracker/metrics.py) against independent checks.

* GOSPA (alpha = 2) against a brute-force minimum over every partial assignment of small sets, and its
  decomposition gospa^p = localisation + c^p/2 (missed + false);
* hand-built track histories with a known number of ID switches, swaps, restarts, fragmentations and breaks
  (the definitions of CLEAR MOT, Bernardin & Stiefelhagen 2008, and of py-motmetrics' fragmentations),
  among them crossing targets whose tracks never change target but whose per-scan least-distance matching
  re-pairs them for a scan (the former ``id_swaps``, now ``assignment_changes``).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.pcl_tracker.metrics import gospa, identity_metrics


def brute_force_gospa(X: np.ndarray, Y: np.ndarray, c: float, p: float) -> float:
    """min over all partial one-to-one assignments of sum d^p + c^p/2 (unassigned), any pair allowed."""
    m, n = len(X), len(Y)
    best = 0.5 * c**p * (m + n)
    for k in range(1, min(m, n) + 1):
        for xs in itertools.combinations(range(m), k):
            for ys in itertools.permutations(range(n), k):
                cost = sum(float(np.linalg.norm(X[i] - Y[j])) ** p for i, j in zip(xs, ys, strict=True))
                best = min(best, cost + 0.5 * c**p * (m + n - 2 * k))
    return best ** (1.0 / p)


points = st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50)), min_size=0, max_size=4)


@settings(max_examples=80, deadline=None)
@given(X=points, Y=points, c=st.floats(0.5, 80.0), p=st.sampled_from([1.0, 2.0]))
def test_gospa_equals_the_brute_force_minimum(X: list, Y: list, c: float, p: float) -> None:
    Xa, Ya = np.array(X, dtype=float).reshape(-1, 2), np.array(Y, dtype=float).reshape(-1, 2)
    g = gospa(Xa, Ya, c, p)
    assert g["gospa"] == pytest.approx(brute_force_gospa(Xa, Ya, c, p), rel=1e-9, abs=1e-9)
    assert g["gospa"] ** p == pytest.approx(g["localisation"] + 0.5 * c**p * (g["missed"] + g["false"]), rel=1e-9)
    assert g["missed"] - g["false"] == len(X) - len(Y)


def test_gospa_hand_computed() -> None:
    X = np.array([[0.0, 0.0], [10.0, 0.0]])  # truths
    Y = np.array([[0.0, 3.0], [100.0, 0.0], [200.0, 0.0]])  # estimates
    g = gospa(X, Y, c=5.0, p=2.0)
    # (0,0)-(0,3) assigned (9); (10,0) missed; two false: 9 + 25/2 * 3
    assert (g["localisation"], g["missed"], g["false"]) == (9.0, 1.0, 2.0)
    assert g["gospa"] == pytest.approx(np.sqrt(9.0 + 12.5 * 3))


def frames(truth: dict[int, list[float]], tracks: dict[int, list[float | None]]) -> tuple[list, list]:
    """Per-scan dicts from 1-D position series (None: absent at that scan)."""
    n = len(next(iter(truth.values())))
    tf = [{i: np.array([v[k], 0.0, 0.0]) for i, v in truth.items() if v[k] is not None} for k in range(n)]
    hf = [{h: np.array([v[k], 0.0, 0.0]) for h, v in tracks.items() if v[k] is not None} for k in range(n)]
    return tf, hf


def plain_changes(tf: list, hf: list, T: float) -> int:
    """The former count: least-distance matching per scan alone, a target whose track id changed."""
    from services.pcl_tracker.metrics import match_tracks

    prev: dict[int, int] = {}
    changes = 0
    for t, h in zip(tf, hf, strict=True):
        ti, hi = list(t), list(h)
        cur = {
            ti[b]: hi[a]
            for a, b in match_tracks(np.array([h[x] for x in hi]).reshape(-1, 3), np.array([t[x] for x in ti]), T)
        }
        changes += sum(1 for i, v in prev.items() if i in cur and cur[i] != v)
        prev = cur
    return changes


def test_crossing_targets_with_lagging_tracks_have_no_switch() -> None:
    """A and B cross at scan 5; each track lags its own target by 150 m. The per-scan matching pairs them the
    other way at scan 6 (50 + 50 < 150 + 150) and back at 7: 4 changes, none of them a switch."""
    k = np.arange(12)
    A, B = -500.0 + 100.0 * k, 500.0 - 100.0 * k
    tf, hf = frames({0: list(A), 1: list(B)}, {1: list(A - 150.0), 2: list(B + 150.0)})
    m = identity_metrics(tf, hf, threshold_m=500.0)
    assert (m["id_switches"], m["id_swaps"], m["id_restarts"], m["fragmentations"], m["breaks"]) == (0, 0, 0, 0, 0)
    assert plain_changes(tf, hf, 500.0) == 4


def test_tracks_that_exchange_targets_are_two_swaps() -> None:
    """Track 1 follows A until the crossing, then B (and track 2 the other way): both targets switch, as swaps."""
    k = np.arange(16)
    A, B = -500.0 + 100.0 * k, 500.0 - 100.0 * k
    t1 = np.where(k <= 5, A, B)
    t2 = np.where(k <= 5, B, A)
    tf, hf = frames({0: list(A), 1: list(B)}, {1: list(t1), 2: list(t2)})
    m = identity_metrics(tf, hf, threshold_m=500.0)
    assert (m["id_switches"], m["id_swaps"], m["id_restarts"], m["fragmentations"], m["breaks"]) == (2, 2, 0, 0, 0)
    # persistence keeps the old pairs while they are within 500 m (scans 6-7), then both re-pair at scan 8
    assert m["matches"][7] == {0: 1, 1: 2} and m["matches"][8] == {0: 2, 1: 1}


def test_restart_after_a_gap_is_a_switch_a_restart_and_a_fragmentation() -> None:
    x = [100.0 * i for i in range(10)]
    t1 = [*x[:5], None, None, None, None, None]
    t3 = [None] * 7 + x[7:]
    tf, hf = frames({0: x}, {1: t1, 3: t3})
    m = identity_metrics(tf, hf, threshold_m=300.0)
    assert (m["id_switches"], m["id_swaps"], m["id_restarts"], m["fragmentations"], m["breaks"]) == (1, 0, 1, 1, 1)


def test_same_track_back_after_a_gap_is_a_fragmentation_only() -> None:
    x = [100.0 * i for i in range(8)]
    t1: list[float | None] = list(x)
    t1[3] = 5000.0  # far off for one scan (a wild estimate), then back
    tf, hf = frames({0: x}, {1: t1})
    m = identity_metrics(tf, hf, threshold_m=300.0)
    assert (m["id_switches"], m["fragmentations"], m["breaks"]) == (0, 1, 1)


def test_a_track_taking_over_another_target_while_the_first_lives_on_is_a_swap() -> None:
    """Track 1 jumps from A to B at scan 4 while B's own track 2 ends there; A is left untracked, B switches
    from 2 to 1, which followed A before: a swap, not a restart."""
    A = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    B = [2000.0] * 6
    t1 = [0.0, 0.0, 0.0, 0.0, 2000.0, 2000.0]
    t2: list[float | None] = [2000.0, 2000.0, 2000.0, 2000.0, None, None]
    tf, hf = frames({0: A, 1: B}, {1: t1, 2: t2})
    m = identity_metrics(tf, hf, threshold_m=300.0)
    assert (m["id_switches"], m["id_swaps"], m["id_restarts"], m["breaks"]) == (1, 1, 0, 1)


def test_targets_appearing_late_are_not_fragmented() -> None:
    x: list[float | None] = [None, None, 0.0, 100.0, 200.0]
    tf, hf = frames({0: x}, {4: [None, None, None, 110.0, 190.0]})
    m = identity_metrics(tf, hf, threshold_m=300.0)
    assert (m["id_switches"], m["fragmentations"], m["breaks"]) == (0, 0, 0)
