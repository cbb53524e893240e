"""rd_nav service (digest 002, issue 5) throughput: RD-LBL cycles per second through ONE service process, over a real
router, fed by the real player as fast as it can publish (``--rate 0``).

Real processes: a ``fixstream router``, ``fixstream run rd_nav`` (instance ``auv4``, the service's defaults: 1,000
particles, the EKF shadow, DR-propagated fixes at 1 Hz and after every cycle) and ``fixstream play`` on the digest's
REF inside scenario (``rd_group``: three beacons, auv4 on the 72-gon, DVL and attitude at 1 Hz, depth and sound speed
every 10 s, three packets per 10 s cycle), 2 h of data = 720 cycles. Two cases:

* ``open loop``: the group keeps the REF assignment (``coordinator: false``): nothing but the player limits the input;
* ``closed loop``: with ``fixstream run coordinator`` too, the player waiting for its replies (one per status report
  and per packet heard at the base: four round trips per cycle).

This process subscribes to the service's ``TdoaCycle`` outputs (one per cycle) and reads the service's CPU time
from ``/proc`` when the 20th has arrived and again at the last: the steady-state CPU per cycle and the wall-clock
cycles per second between those two moments (best of two runs, each with a fresh service; the machine is shared,
the load average is printed with the figures). The same messages through the service's offline path
(``run_offline``: decode, core, encode, no Zenoh) in this process give the estimator's own cost.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import yaml

from services.player.scenario import load_scenario
from services.player.timeline import scenario_events
from services.rd_nav.service import RdNavService, RdNavSettings, cycle_key

from .report import emit
from .service_harness import client_env, play_timed, start_service, stop
from .stack import router

DURATION_S = 7200.0
CYCLE_S = 10.0
WARM = 20
REPEATS = 2


def scenario_doc(closed_loop: bool) -> dict[str, object]:
    wait = ["rd_nav/auv4", *(["coordinator/group1"] if closed_loop else [])]
    return {
        "format": 1,
        "name": f"bench_rd_nav_{'closed' if closed_loop else 'open'}",
        "seed": 1,
        "duration_s": DURATION_S,
        "frame_id": "local_enu",
        "wait_for": wait,
        "wait_timeout_s": 60,
        "simulators": [
            {
                "kind": "rd_group",
                "id": "group1",
                "params": {"preset": "ref", "path": "inside", "coordinator": closed_loop, "truth_period_s": 0.0},
            }
        ],
    }


def offline_cost(path: Path) -> tuple[float, int, int]:
    """The service's offline path on the vehicle's messages: CPU s per cycle, cycles, messages."""
    events = scenario_events(load_scenario(path))
    feed = [(e.key, e.msg) for e in events if e.key.startswith("fixstream/sensor/auv4/")]
    best = float("inf")
    cycles = 0
    for _ in range(2):
        svc = RdNavService(RdNavSettings(instance="auv4"))
        c0 = time.process_time()
        out = svc.run_offline(feed)
        best = min(best, time.process_time() - c0)
        cycles = sum(o.key == cycle_key("auv4") for o in out)
    return best / cycles, cycles, len(feed)


def run_case(endpoint: str, tmp: Path, closed_loop: bool) -> dict[str, float]:
    path = tmp / f"bench_{closed_loop}.yaml"
    path.write_text(yaml.safe_dump(scenario_doc(closed_loop)))
    offline_s, total, n_msgs = offline_cost(path)
    service = start_service("rd_nav", client_env(endpoint, {"FIXSTREAM_RD_NAV_INSTANCE": "auv4"}))
    coordinator = None
    if closed_loop:
        coordinator = start_service("coordinator", client_env(endpoint, {"FIXSTREAM_COORDINATOR_INSTANCE": "group1"}))
    try:
        w = play_timed(endpoint, path, cycle_key("auv4"), service.pid, WARM, total, timeout_s=300)
    finally:
        stop(service, coordinator)
    timed = total - WARM
    cpu = w.cpu_s / timed
    return {
        "cycles": total,
        "messages_to_service": n_msgs,
        "timed_cycles": timed,
        "service_cpu_ms_per_cycle": round(cpu * 1e3, 3),
        "cycles_per_s_cpu": round(1.0 / cpu, 1),
        "cycles_per_s_wall": round(timed / w.wall_s, 1),
        "player_wall_s": round(w.player_wall_s, 2),
        "offline_cpu_ms_per_cycle": round(offline_s * 1e3, 3),
        "realtime_factor": round(timed / w.wall_s * CYCLE_S, 1),
    }


def main() -> None:
    rows = []
    figures: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as tmp, router() as endpoint:
        for closed in (False, True):
            runs = [run_case(endpoint, Path(tmp), closed) for _ in range(REPEATS)]
            f = min(runs, key=lambda r: r["service_cpu_ms_per_cycle"])  # the least disturbed repetition
            name = "closed loop" if closed else "open loop"
            figures[name] = f
            rows.append(
                (
                    name,
                    f["timed_cycles"],
                    f["service_cpu_ms_per_cycle"],
                    f["offline_cpu_ms_per_cycle"],
                    f["cycles_per_s_cpu"],
                    f["cycles_per_s_wall"],
                    f"{f['realtime_factor']:.0f}x",
                    f["player_wall_s"],
                )
            )
    emit(
        "rd_nav_service",
        [
            "case",
            "timed cycles",
            "service CPU ms / cycle",
            "offline CPU ms / cycle",
            "cycles / s (CPU)",
            "cycles / s (wall)",
            "real time",
            "player wall s",
        ],
        rows,
        {"cases": figures, "load_average_1min": round(os.getloadavg()[0], 2)},
    )


if __name__ == "__main__":
    main()
