"""A generator of manoeuvring flights for the attitude estimator's own scenario family (issue 15).

The digest's scenario (§3.1) is one straight, level flight. Users fly turns: this module draws flights of light
and transport aircraft as the issue describes them (75-250 m/s, coordinated turns of 10-45 deg bank, climbs and
descents, 2 g turns and parabolic manoeuvres; a 9S15-like radar, 5 s scan, 8-140 km), as target mappings in the
public scenario format of the ``attitude`` player plugin (``start`` + ``segments``, ``wander``), so the scenario
files hold the flights themselves and the generator is needed only to make new ones::

    python -m services.attitude.flights --seed 15042 --out scenarios/

Every flight starts straight (60-150 s, for the filters to converge), then flies one or two manoeuvres separated
by straight legs. Roll-in and roll-out take 3-5 s (a linear bank ramp), as aircraft do. Every flight carries the
same small random wander (light turbulence and pilot corrections, :class:`~.simulation.Wander`): 0.2 m/s^2 across
and normal to the path, 0.05 m/s^2 along it, 20 s correlation. A flight is redrawn until its whole path stays
between 8 and 140 km of the radar and between 300 and 12,000 m of height.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .simulation import G_TRUTH_MPS2, FlightPlan, Segment, fly, paper_plan, true_spherical

#: scan period (s), scans per flight, and the radar preset of the family
SCAN_S = 5.0
N_SCANS = 100
DURATION_S = SCAN_S * (N_SCANS - 1)
RANGE_M = (8e3, 140e3)
HEIGHT_M = (300.0, 12e3)
WANDER: dict[str, float] = {"sigma_lat_mps2": 0.2, "sigma_vert_mps2": 0.2, "sigma_long_mps2": 0.05, "tau_s": 20.0}

#: the flight kinds: (speed range m/s, altitude range m, bank range deg)
KINDS: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    "light_turn": ((75.0, 120.0), (500.0, 3000.0), (15.0, 45.0)),
    "transport_turn": ((150.0, 250.0), (3000.0, 10000.0), (10.0, 30.0)),
    "climb": ((75.0, 250.0), (1000.0, 6000.0), (0.0, 0.0)),
    "turn_2g": ((200.0, 250.0), (3000.0, 8000.0), (60.0, 60.0)),
    "parabolic": ((200.0, 250.0), (3000.0, 6000.0), (0.0, 0.0)),
}


def _u(rng: np.random.Generator, lo: float, hi: float, digits: int = 1) -> float:
    return round(float(rng.uniform(lo, hi)), digits)


def _turn(rng: np.random.Generator, speed: float, bank_range: tuple[float, float]) -> list[dict[str, Any]]:
    """Roll in, hold a coordinated level turn for a 60-240 deg heading change (90-180 at 2 g), roll out."""
    bank = _u(rng, *bank_range) * (1.0 if rng.random() < 0.5 else -1.0)
    ramp = _u(rng, 3.0, 5.0)
    rate_dps = math.degrees(G_TRUTH_MPS2 * math.tan(math.radians(abs(bank))) / speed)
    change = float(rng.uniform(90.0, 180.0) if abs(bank) >= 60.0 else rng.uniform(60.0, 240.0))
    hold = round(max(change / rate_dps - ramp, 5.0), 1)
    return [
        {"duration_s": ramp, "bank_deg": [0.0, bank]},
        {"duration_s": hold, "bank_deg": bank},
        {"duration_s": ramp, "bank_deg": [bank, 0.0]},
    ]


def _climb(rng: np.random.Generator) -> list[dict[str, Any]]:
    """Pull up to a 3-10 deg climb (or push down to a descent) at 0.5-1 deg/s, hold 30-90 s, level off."""
    gamma = _u(rng, 3.0, 10.0) * (1.0 if rng.random() < 0.6 else -1.0)
    rate = _u(rng, 0.5, 1.0, 2) * math.copysign(1.0, gamma)
    t_pitch = round(abs(gamma / rate), 1)
    return [
        {"duration_s": t_pitch, "pitch_rate_dps": rate},
        {"duration_s": _u(rng, 30.0, 90.0)},
        {"duration_s": t_pitch, "pitch_rate_dps": -rate},
    ]


def _time_to_pitch(plan: FlightPlan, segment: Segment, t0: float, pitch_deg: float, rising: bool) -> float:
    """Time (s, 0.1 s steps) that ``segment`` flown from t0 after ``plan`` needs to bring the flight-path angle
    past ``pitch_deg`` (upwards if ``rising``)."""
    probe = FlightPlan(plan.p0_m, plan.speed_mps, plan.psi_deg, plan.theta_deg, (*plan.segments, segment))
    t = t0 + np.arange(0.0, segment.duration_s, 0.1)
    theta = np.degrees(fly(probe, t).theta)
    past = theta >= pitch_deg if rising else theta <= pitch_deg
    return round(float(t[int(np.argmax(past))] - t0) if past.any() else segment.duration_s, 1)


def _parabolic(rng: np.random.Generator, plan: FlightPlan, t0: float) -> list[dict[str, Any]]:
    """2 g pull-up to 25-40 deg, push-over to a zero-g parabola down to -(20-30) deg, 2 g pull-out to level, n = 1."""
    up, down = _u(rng, 25.0, 40.0), -_u(rng, 20.0, 30.0)
    segs: list[Segment] = [Segment(3.0, load_factor=(1.0, 2.0), gravity_speed=True)]
    hold = Segment(60.0, load_factor=(2.0, 2.0), gravity_speed=True)
    t = t0 + 3.0
    probe = FlightPlan(plan.p0_m, plan.speed_mps, plan.psi_deg, plan.theta_deg, (*plan.segments, *segs))
    segs.append(Segment(max(_time_to_pitch(probe, hold, t, up, True), 1.0), load_factor=(2.0, 2.0), gravity_speed=True))
    segs.append(Segment(3.0, load_factor=(2.0, 0.0), gravity_speed=True))
    t += segs[-2].duration_s + 3.0
    probe = FlightPlan(plan.p0_m, plan.speed_mps, plan.psi_deg, plan.theta_deg, (*plan.segments, *segs))
    arc = Segment(60.0, load_factor=(0.0, 0.0), gravity_speed=True)
    segs.append(
        Segment(max(_time_to_pitch(probe, arc, t, down, False), 1.0), load_factor=(0.0, 0.0), gravity_speed=True)
    )
    segs.append(Segment(3.0, load_factor=(0.0, 2.0), gravity_speed=True))
    t += segs[-2].duration_s + 3.0
    probe = FlightPlan(plan.p0_m, plan.speed_mps, plan.psi_deg, plan.theta_deg, (*plan.segments, *segs))
    pull = Segment(60.0, load_factor=(2.0, 2.0), gravity_speed=True)
    segs.append(
        Segment(max(_time_to_pitch(probe, pull, t, -2.0, True), 1.0), load_factor=(2.0, 2.0), gravity_speed=True)
    )
    segs.append(Segment(3.0, load_factor=(2.0, 1.0), gravity_speed=True))
    out = []
    for s in segs:
        n0, n1 = s.load_factor if s.load_factor is not None else (1.0, 1.0)
        out.append({"duration_s": s.duration_s, "load_factor": n0 if n0 == n1 else [n0, n1], "gravity_speed": True})
    return out


def _segment(d: dict[str, Any]) -> Segment:
    """A mapping of the scenario format -> simulation.Segment (what the player plugin builds)."""

    def pair(v: Any) -> tuple[float, float]:
        return (float(v[0]), float(v[1])) if isinstance(v, list) else (float(v), float(v))

    return Segment(
        float(d["duration_s"]),
        pitch_rate_dps=pair(d.get("pitch_rate_dps", 0.0)),
        bank_deg=pair(d["bank_deg"]) if "bank_deg" in d else None,
        load_factor=pair(d["load_factor"]) if "load_factor" in d else None,
        gravity_speed=bool(d.get("gravity_speed", False)),
    )


def random_flight(rng: np.random.Generator, kind: str, target_id: str) -> dict[str, Any]:
    """One flight of ``kind`` (a key of KINDS) as a target mapping of the ``attitude`` player plugin."""
    (v_lo, v_hi), (h_lo, h_hi), banks = KINDS[kind]
    for _ in range(1000):
        speed = _u(rng, v_lo, v_hi)
        start = {
            "range_m": round(float(rng.uniform(15e3, 130e3)), -2),
            "azimuth_deg": _u(rng, 0.0, 360.0),
            "altitude_m": round(float(rng.uniform(h_lo, h_hi)), -1),
            "heading_deg": _u(rng, 0.0, 360.0),
            "speed_mps": speed,
        }
        p0 = paper_plan(start["range_m"], start["azimuth_deg"], start["altitude_m"]).p0_m
        segments: list[dict[str, Any]] = [{"duration_s": _u(rng, 60.0, 150.0, 0)}]
        n_manoeuvres = 1 if kind in ("parabolic", "turn_2g") or rng.random() < 0.5 else 2
        for m in range(n_manoeuvres):
            if m:
                segments.append({"duration_s": _u(rng, 40.0, 100.0, 0)})
            if kind == "climb":
                segments += _climb(rng)
            elif kind == "parabolic":
                plan = FlightPlan(p0, speed, start["heading_deg"], 0.0, tuple(_segment(s) for s in segments))
                segments += _parabolic(rng, plan, sum(s["duration_s"] for s in segments))
            else:
                segments += _turn(rng, speed, banks)
        plan = FlightPlan(p0, speed, start["heading_deg"], 0.0, tuple(_segment(s) for s in segments))
        truth = fly(plan, np.arange(N_SCANS, dtype=np.float64) * SCAN_S)
        r, _, _ = true_spherical(truth.p)
        height = truth.p[:, 1]
        inside = r.min() >= RANGE_M[0] and r.max() <= RANGE_M[1]
        inside = inside and HEIGHT_M[0] <= height.min() and height.max() <= HEIGHT_M[1]
        if inside and np.linalg.norm(truth.v, axis=1).min() >= 60.0:
            return {
                "id": target_id,
                "phase_s": _u(rng, 0.0, SCAN_S, 2),
                "start": start,
                "segments": segments,
                "wander": dict(WANDER),
            }
    raise RuntimeError(f"no {kind} flight inside the radar's coverage after 1000 draws")


#: the family's scenario files: name -> (description, [(kind, count)])
FILES: dict[str, tuple[str, list[tuple[str, int]]]] = {
    "attitude_turns_light": ("light aircraft (75-120 m/s) in coordinated turns of 15-45 deg bank", [("light_turn", 6)]),
    "attitude_turns_transport": (
        "transport aircraft (150-250 m/s) in coordinated turns of 10-30 deg bank",
        [("transport_turn", 6)],
    ),
    "attitude_climbs": ("climbs and descents of 3-10 deg at 75-250 m/s", [("climb", 6)]),
    "attitude_agile": (
        "2 g level turns (60 deg bank) and parabolic (2 g / zero-g / 2 g) manoeuvres",
        [("turn_2g", 3), ("parabolic", 3)],
    ),
}


def scenario_document(name: str, seed: int) -> dict[str, Any]:
    """The scenario file ``name`` (a key of FILES) with flights drawn from ``seed``."""
    what, kinds = FILES[name]
    rng = np.random.default_rng([seed, sum(map(ord, name))])
    targets = []
    for kind, count in kinds:
        for i in range(count):
            targets.append(random_flight(rng, kind, f"{kind.replace('_', '')}{i + 1}"))
    return {
        "format": 1,
        "name": name,
        "description": f"Radar r1 (9S15 sigmas, 5 s scan) sees {len(targets)} aircraft for {DURATION_S:g} s: {what}, "
        "each after a straight start and with small random wander (light turbulence). Generated by "
        f"services/attitude/flights.py (seed {seed}); the default preset is scored, set params.config.preset "
        "to paper for the paper's filter.",
        "seed": seed,
        "duration_s": DURATION_S,
        "frame_id": "local_enu",
        "wait_for": ["recorder", "attitude/r1"],
        "wait_timeout_s": 60,
        "simulators": [
            {
                "kind": "attitude",
                "id": "r1",
                "params": {"site_id": "r1", "radar": "9S15", "scan_period_s": SCAN_S, "targets": targets},
            }
        ],
        "estimators": [{"kind": "attitude", "instance": "r1", "params": {"reference": False}}],
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=15042)
    ap.add_argument("--out", type=Path, default=Path("scenarios"))
    args = ap.parse_args(argv)
    for name in FILES:
        doc = scenario_document(name, args.seed)
        header = (
            f"# {name}: the attitude estimator's manoeuvring scenario family (issue 15; docs/attitude.md).\n"
            f"# Generated by `python -m services.attitude.flights --seed {args.seed}`; format: docs/scenarios.md.\n"
            f"#   fixstream mc {name} --runs 100 --seed 1 --out m.json\n"
        )
        path = args.out / f"{name}.yaml"
        path.write_text(header + yaml.safe_dump(doc, sort_keys=False, width=120, default_flow_style=None))
        print(path)


if __name__ == "__main__":
    main()
