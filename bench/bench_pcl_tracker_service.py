"""PCL tracker service: scans per second through ``fixstream run pcl_tracker`` with the player flat out.

Real processes on loopback: a ``fixstream router``, one ``fixstream run pcl_tracker`` configured by its
``FIXSTREAM_PCL_TRACKER_*`` environment as in compose.yaml, and ``fixstream play SCENARIO --rate 0``
(which waits for the tracker's liveliness token, then publishes as fast as the network takes the
messages; the tracker queues what it has not processed yet). This process subscribes to the tracker's
output key and notes the arrival time and size of every scan report, without decoding it.

Figures per case: the player's rate (scans/s over its whole run, simulation included, from its own log
line); the tracker's output rate (reports/s between the first and the last report: decoding and validating
the scan, the core, encoding and publishing the report), overall and over the reports that arrived after
the player had exited (the tracker working through its queue without the player competing for the two
cores); the core's mean CPU and wall time per scan (tracker status: thread CPU time and wall time of
``PclTracker.step``); the mean size of a report on the wire; and the mean number of live tracks per report
(the reports are decoded after the timing, which also checks that none was lost). Cases: the paper's
single target; 20 targets with 10 clutter plots per scan (the many-target scenario's configuration,
q = 10, M/N = 3/4, range-sum and Doppler plots); 100 targets with 100 clutter plots per scan; and
100 targets with 1,000 clutter plots per scan with the limits raised so that every scan is fully
processed (initiation included).
"""

from __future__ import annotations

import json
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import yaml
import zenoh

from schemas.pcl_tracker import PclScanReport
from services.pcl_tracker.service import output_key
from shared import codec
from shared.session import open_session
from shared.settings import ZenohSettings

from .report import emit
from .service_harness import client_env, play, service_status, start_service, stop
from .stack import router

PAPER = {"receiver_id": "rx1", "illuminator_id": "tx-fm-98.1", "tx_position_enu_m": [8000, 0, 300]}
DVBT = {"receiver_id": "rx1", "illuminator_id": "tx-dvbt-530", "tx_position_enu_m": [-12000, 15000, 400]}
MANY_ENV = {"WAVELENGTH_M": "0.566", "Q_ACCEL_VAR_M2S4": "10", "CONFIRM_M": "3", "CONFIRM_N": "4"}
FULL_LIMITS = {"MAX_PLOTS_PER_SCAN": "1000000", "MAX_TENTATIVE_TRACKS": "1000000", "MAX_CONFIRMED_TRACKS": "100000"}


def case_scenario(name: str, pair: dict[str, Any], n_scans: int, sim: dict[str, Any]) -> dict[str, Any]:
    return {
        "format": 1,
        "name": name,
        "seed": 1,
        "duration_s": 3.0 * (n_scans - 1),
        "frame_id": "pcl_enu",
        "wait_for": [f"pcl_tracker/{name}"],
        "wait_timeout_s": 120,
        "simulators": [{"kind": "pcl_tracker", "id": "pcl", "params": {**pair, "scan_period_s": 3.0, **sim}}],
    }


CASES: list[tuple[str, str, dict[str, Any], dict[str, str]]] = [
    (
        "1 target, no clutter (paper geometry and configuration)",
        "paper",
        case_scenario(
            "paper",
            PAPER,
            301,
            {"targets": [{"id": "target1", "position_m": [-40000, -30000, 3000], "speed_mps": 100, "course_deg": 45}]},
        ),
        {},
    ),
    (
        "20 targets, 10 clutter/scan (q = 10, M/N = 3/4)",
        "many20",
        case_scenario(
            "many20",
            DVBT,
            101,
            {
                "random_targets": {"count": 20},
                "p_detection": 0.95,
                "clutter": {"rate_per_scan": 10, "rb_range_m": [0, 150000]},
                "range_form": "range_sum",
                "velocity_form": "doppler",
                "wavelength_m": 0.566,
            },
        ),
        MANY_ENV,
    ),
    (
        "100 targets, 100 clutter/scan (q = 10, M/N = 3/4)",
        "many100",
        case_scenario(
            "many100",
            DVBT,
            101,
            {
                "random_targets": {"count": 100},
                "p_detection": 0.95,
                "clutter": {"rate_per_scan": 100, "rb_range_m": [0, 150000]},
                "wavelength_m": 0.566,
            },
        ),
        MANY_ENV,
    ),
    (
        "100 targets, 1000 clutter/scan, limits raised (full initiation)",
        "clutter1000",
        case_scenario(
            "clutter1000",
            DVBT,
            61,
            {
                "random_targets": {"count": 100},
                "p_detection": 0.95,
                "clutter": {"rate_per_scan": 1000, "rb_range_m": [0, 150000]},
                "wavelength_m": 0.566,
            },
        ),
        {**MANY_ENV, **FULL_LIMITS},
    ),
]


def run_case(
    endpoint: str, workdir: Path, instance: str, spec: dict[str, Any], env_extra: dict[str, str]
) -> dict[str, Any]:
    pair = spec["simulators"][0]["params"]
    n_scans = round(spec["duration_s"] / 3.0) + 1
    path = workdir / f"{instance}.yaml"
    path.write_text(yaml.safe_dump(spec))
    base_env = client_env(endpoint, clean=True)
    settings = {
        "FIXSTREAM_PCL_TRACKER_INSTANCE": instance,
        "FIXSTREAM_PCL_TRACKER_RECEIVER_ID": pair["receiver_id"],
        "FIXSTREAM_PCL_TRACKER_ILLUMINATOR_ID": pair["illuminator_id"],
        "FIXSTREAM_PCL_TRACKER_TX_POSITION_ENU_M": json.dumps(pair["tx_position_enu_m"]),
        **{f"FIXSTREAM_PCL_TRACKER_{k}": v for k, v in env_extra.items()},
    }
    env = client_env(endpoint, settings, clean=True)
    session = open_session(ZenohSettings(mode="client", connect=[endpoint]))
    arrivals: list[tuple[float, int]] = []
    payloads: list[bytes] = []
    lock = threading.Lock()

    def on_report(sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()
        with lock:
            arrivals.append((time.perf_counter(), len(payload)))
            payloads.append(payload)

    sub = session.declare_subscriber(output_key(pair["receiver_id"], pair["illuminator_id"]), on_report)
    tracker = start_service("pcl_tracker", env, quiet=True)
    try:
        t0 = time.perf_counter()
        player_s = play(path, base_env).player_s
        player_done = time.perf_counter()
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline:
            with lock:
                if len(arrivals) >= n_scans:
                    break
            time.sleep(0.05)
        status = service_status(session, "pcl_tracker", instance)
    finally:
        stop(tracker)
        sub.undeclare()
        session.close()
    with lock:
        got = list(arrivals)
    if len(got) < n_scans:
        raise RuntimeError(f"{instance}: {len(got)} of {n_scans} reports arrived")
    span = got[-1][0] - got[0][0]
    backlog = [t for t, _ in got if t > player_done]
    reports = [codec.decode(b, codec.encoding_of(PclScanReport)) for b in payloads]  # after the timing
    assert all(isinstance(r, PclScanReport) for r in reports)
    assert [r.header.seq for r in reports] == list(range(n_scans)), "a report was lost or reordered"
    live = [r.n_tentative + r.n_confirmed for r in reports]  # type: ignore[attr-defined]
    return {
        "scans": n_scans,
        "player_scans_per_s": round(n_scans / player_s, 1) if player_s > 0 else None,
        "service_scans_per_s": round((len(got) - 1) / span, 1) if span > 0 else None,
        "service_scans_per_s_after_player": (
            round((len(backlog) - 1) / (backlog[-1] - backlog[0]), 1) if len(backlog) >= 10 else None
        ),
        "core_mean_ms": status.get("mean_scan_ms"),
        "core_mean_cpu_ms": status.get("mean_scan_cpu_ms"),
        "mean_report_kb": round(sum(n for _, n in got) / len(got) / 1024.0, 1),
        "live_tracks_mean": round(sum(live) / len(live), 1),
        "live_tracks_max": max(live),
        "wall_s": round(got[-1][0] - t0, 2),
        "rejected": status.get("counters", {}).get("rejected"),
    }


def main() -> None:
    rows = []
    figures: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp, router() as endpoint:
        for label, instance, spec, env_extra in CASES:
            r = run_case(endpoint, Path(tmp), instance, spec, env_extra)
            figures[instance] = {"case": label, **r}
            rows.append(
                (
                    label,
                    r["scans"],
                    r["player_scans_per_s"],
                    r["service_scans_per_s"],
                    r["service_scans_per_s_after_player"] or "",
                    r["core_mean_cpu_ms"],
                    r["core_mean_ms"],
                    r["mean_report_kb"],
                    r["live_tracks_mean"],
                )
            )
    emit(
        "pcl_tracker_service",
        [
            "case",
            "scans",
            "player scans/s",
            "service scans/s",
            "service scans/s after the player",
            "core CPU ms/scan",
            "core wall ms/scan",
            "report kB",
            "live tracks (mean)",
        ],
        rows,
        figures,
    )


if __name__ == "__main__":
    main()
