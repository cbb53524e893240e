"""Attitude estimator (issue 15): how far a filter that is TOLD the flight phase gets in turns -- the bound that
mode detection leaves, and what learning the turn rate costs.

On the two turn files of the manoeuvring family (``attitude_turns_light``, ``attitude_turns_transport``: the same
plots as ``fixstream mc``'s runs from seed 1), three single-model filters switched at the truth's commanded phase
(the ``turn`` phase of the metrics, commanded roll above 5 deg) instead of by an IMM:

* ``mode oracle, quadrature``: the default preset's straight model outside turns; from the first plot of a turn
  the CT model of the default bank (Gauss-Hermite prediction over omega, ``models.ct_predict``), started from the
  straight state with the implied turn rate plus a prior spread of ``ORACLE_OMEGA_SIGMA`` (0.05 rad/s; 0.1 and 0.2
  were worse); back to the straight model (the 9-state part) at the first plot after the turn;
* ``mode oracle, EKF``: the same with the CT model's EKF prediction (``models.ct_step``);
* ``turn-rate oracle``: the same as the first, but the CT model is given the TRUE turn rate at every plot.

Heading RMS (deg) in the turn phase, on straight legs, on steady legs (30 s after a turn), from scan 20, like the
family statistics (bench_attitude_manoeuvre). The IMM of the default preset is run on the same plots for comparison.

    ATTITUDE_ORACLE_RUNS=20 python -m bench attitude_oracle
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

from schemas import RadarPlot, Truth
from services.attitude.angles import AngleConventions, angle_block
from services.attitude.config import MANOEUVRE_MODELS, AttitudeConfig
from services.attitude.filter import update
from services.attitude.geometry import convert_plot
from services.attitude.imm import augment, model_matrices
from services.attitude.initiation import fsf_estimate
from services.attitude.mc import Params, _site, radar_frame_truth, run_core
from services.attitude.models import OMEGA, ct_predict, ct_step
from services.player.scenario import load_scenario
from services.player.timeline import build, player_source, stamp
from tools.montecarlo import EVENT_INSTANCE

from .bench_attitude_manoeuvre import SCENARIOS, SEED
from .report import emit

FILES = ("attitude_turns_light", "attitude_turns_transport")
ORACLE_OMEGA_SIGMA = 0.05
FIRST_SCAN = 20
D2R = math.pi / 180.0
MODES = ("mode oracle, quadrature", "mode oracle, EKF", "turn-rate oracle")


def _phase(truth: Truth) -> str | None:
    if truth.extra["turn"] > 0.5:
        return "turn"
    return "straight" if truth.extra["manoeuvre"] < 0.5 else None


def oracle_run(events: list[Any], scenario: Any, mode: str) -> dict[str, list[float]]:
    """Squared heading errors (deg^2) per phase of one run of one oracle filter."""
    _, site_pos = _site(Params(reference=False), scenario)
    cfg = AttitudeConfig()
    sig = cfg.measurement_sigmas()
    straight, turn = MANOEUVRE_MODELS[0], MANOEUVRE_MODELS[1]
    assert straight.kind == "singer" and turn.kind == "ct" and turn.sigma_accel_mps2 and turn.tau_s
    truths = {
        (e.msg.platform, e.msg.header.stamp_ns): radar_frame_truth(e.msg, site_pos)
        for e in events
        if isinstance(e.msg, Truth)
    }
    tracks: dict[str, dict[str, Any]] = {}
    out: dict[str, list[float]] = {"turn": [], "straight": [], "steady": []}
    conv = AngleConventions()
    for e in events:
        m = e.msg
        if not isinstance(m, RadarPlot):
            continue
        z, rz = convert_plot(
            m.range_m,
            (m.az_deg % 360.0) * D2R,
            m.el_deg * D2R,
            sig.sigma_r_m,
            sig.sigma_az_deg * D2R,
            sig.sigma_el_deg * D2R,
        )
        t = m.header.stamp_ns / 1e9
        tr = tracks.setdefault(m.target_id, {"buf": [], "x": None, "k": 0})
        tr["k"] += 1
        truth = truths[(m.target_id, m.header.stamp_ns)]
        phase = _phase(truth)
        if tr["x"] is None:
            tr["buf"].append((t, z, rz))
            if len(tr["buf"]) == 3:
                taus = np.array([b[0] - t for b in tr["buf"]])
                zs, rs = np.stack([b[1] for b in tr["buf"]]), np.stack([b[2] for b in tr["buf"]])
                tr["x"], tr["p"] = fsf_estimate(taus, zs, rs)
                tr["t"], tr["ct"] = t, False
            continue
        dt, x, p = t - tr["t"], tr["x"], tr["p"]
        if phase == "turn" and not tr["ct"]:
            x10, p10 = np.zeros(10), np.zeros((10, 10))
            x10[:9], p10[:9, :9] = x, p
            augment(x10, p10)
            p10[OMEGA, OMEGA] += ORACLE_OMEGA_SIGMA**2
            x, p, tr["ct"] = x10, p10, True
        elif phase != "turn" and tr["ct"]:
            x, p, tr["ct"] = x[:9].copy(), p[:9, :9].copy(), False
        if tr["ct"]:
            if mode == "turn-rate oracle":
                v, a = truth.velocity_mps, truth.acceleration_mps2
                assert v is not None and a is not None
                x, p = x.copy(), p.copy()
                x[OMEGA] = (v[0] * a[2] - v[2] * a[0]) / (v[0] ** 2 + v[2] ** 2)
                p[OMEGA, :] = p[:, OMEGA] = 0.0
            if mode == "mode oracle, EKF":
                xp, f, q = ct_step(x, dt, turn.sigma_accel_mps2, turn.tau_s, turn.q_omega)
                pp = f @ p @ f.T + q
            else:
                xp, pp = ct_predict(x, p, dt, turn.sigma_accel_mps2, turn.tau_s, turn.q_omega)
        else:
            f, q = model_matrices(straight, dt)
            xp, pp = f @ x, f @ p @ f.T + q
        tr["x"], tr["p"], _ = update(xp, pp, z, rz)
        tr["t"] = t
        if tr["k"] < FIRST_SCAN or phase is None:
            continue
        vals, _, _ = angle_block(tr["x"][:9].tolist(), conv, None, jacobian=False)
        v = truth.velocity_mps
        assert v is not None
        err = (math.degrees(vals[0] - math.atan2(v[2], v[0])) + 180.0) % 360.0 - 180.0
        out[phase].append(err * err)
        if phase == "straight" and truth.extra["since_manoeuvre_s"] > 30.0:
            out["steady"].append(err * err)
    return out


def main() -> None:
    runs = int(os.environ.get("ATTITUDE_ORACLE_RUNS", "20"))
    sq: dict[str, dict[str, list[float]]] = {k: {"turn": [], "straight": [], "steady": []} for k in (*MODES, "IMM")}
    for name in FILES:
        sc = load_scenario(SCENARIOS / f"{name}.yaml")
        for run in range(runs):
            events = list(stamp(build(sc, SEED, run).raw_events(), player_source(EVENT_INSTANCE)))
            for mode in MODES:
                for ph, v in oracle_run(events, sc, mode).items():
                    sq[mode][ph] += v
            imm = run_core(events, {"reference": False}, sc)
            for rec in imm["targets"].values():
                for k, ph in enumerate(rec["phase"]):
                    e = rec["err"]["psi"][k]
                    if k < FIRST_SCAN - 1 or ph not in ("turn", "straight") or e is None or not math.isfinite(e):
                        continue
                    sq["IMM"][ph].append(e * e)
                    if ph == "straight" and rec["since_manoeuvre_s"][k] > 30.0:
                        sq["IMM"]["steady"].append(e * e)
    rows = []
    figures: dict[str, Any] = {"runs_per_file": runs, "files": list(FILES), "seed": SEED}
    for label, s in sq.items():
        rms = {ph: math.sqrt(float(np.mean(v))) if v else None for ph, v in s.items()}
        ratio = rms["turn"] / rms["straight"] if rms["turn"] and rms["straight"] else None
        rows.append([label, rms["turn"], rms["straight"], rms["steady"], ratio, len(s["turn"])])
        figures[label] = {"rms_deg": rms, "turn_over_straight": ratio}
    emit(
        "attitude_oracle",
        ["filter", "psi turn", "psi straight", "psi steady", "turn / straight", "turn samples"],
        rows,
        figures,
    )


if __name__ == "__main__":
    main()
