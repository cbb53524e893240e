"""Monte-Carlo evaluation of the attitude estimator (§3, §4): many runs of one scenario through ONE core.

Each Monte-Carlo run is a separate target of a single :class:`~services.attitude.core.AttitudeCore` instance
(target ids ``run0``, ``run1``, ...), fed scan by scan exactly as a radar site would feed the service, so the
figures come from the same class, through the same ``step()``, as the service. The noise of all runs is drawn
in one block (common random numbers across configurations with the same seed).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from schemas import Header, RadarPlot
from shared.errors import InputRejected

from .config import AttitudeConfig, MeasurementSigmas, RadarPreset
from .core import AttitudeCore
from .metrics import RunRecorder, aggregate, truth_angles
from .simulation import NS, FlightPlan, fly, measure, paper_plan, scan_times, truth_messages


def monte_carlo_size(confidence_t: float = 1.96, rel_error: float = 0.05) -> int:
    """N = ceil(2 t^2 / delta^2): runs needed to estimate a variance to +-delta at the confidence of t (§3.3)."""
    return math.ceil(2.0 * confidence_t**2 / rel_error**2)


def evaluation_config(
    radar: RadarPreset | None = "9S15",
    sigmas: MeasurementSigmas | None = None,
    sigma_jerk_mps3: float = 0.03,
    **overrides: Any,
) -> AttitudeConfig:
    """The configuration of the digest's reference runs: the paper's filter (``preset="paper"``), angles at every
    scan from scan 3 on.

    The service's suppression rules for undefined angles (v_min, 3 sigma(V_h), 0.1 g) are switched off, because
    the digest's reference figures (P3: ~56-61 deg at scan 3) include every scan's angles; the schema's PSD
    check of the output covariances is skipped for speed (the core keeps them PD by construction) and the raw
    baseline (§2.6) is attached for the P1/P2 comparisons. Everything else is the default configuration.
    """
    fields: dict[str, Any] = {
        "preset": "paper",
        "v_min_mps": 0.0,
        "heading_sigma_factor": 0.0,
        "min_normal_force_g": 0.0,
        "validate_covariances": False,
        "raw_output": True,
        "sigma_jerk_mps3": (sigma_jerk_mps3,) * 3,
        "radar": radar,
    }
    if sigmas is not None:
        fields.update(sigma_r_m=sigmas.sigma_r_m, sigma_az_deg=sigmas.sigma_az_deg, sigma_el_deg=sigmas.sigma_el_deg)
    fields.update(overrides)
    return AttitudeConfig(**fields)


def run_monte_carlo(
    config: AttitudeConfig,
    n_runs: int,
    plan: FlightPlan | None = None,
    n_scans: int = 100,
    seed: int = 0,
    sigmas: MeasurementSigmas | None = None,
    site_id: str = "mc",
) -> dict[str, Any]:
    """Run ``n_runs`` noisy realisations of a flight plan (default: the §3.1 scenario) through one core.

    The measurement noise uses ``sigmas`` (default: the configuration's own sigmas, i.e. a matched filter).
    Returns :func:`~services.attitude.metrics.aggregate` of the per-run records, plus ``rejected`` (the core's
    counters) and ``config`` (the configuration used).
    """
    plan = plan if plan is not None else paper_plan()
    sig = sigmas if sigmas is not None else config.measurement_sigmas()
    times = scan_times(n_scans, config.scan_period_s)
    truth = fly(plan, times)
    stamps = [round(t * NS) for t in times.tolist()]
    truths = truth_messages("target", truth, stamps)
    true_angles = [truth_angles(t, config.los_x, config.gamma_los_form) for t in truths]
    meas = measure(truth, sig, np.random.default_rng(seed), n_runs).tolist()

    core = AttitudeCore(config)
    recorders = [RunRecorder() for _ in range(n_runs)]
    ids = [f"run{n}" for n in range(n_runs)]
    for k, stamp in enumerate(stamps):
        header = Header(stamp_ns=stamp, source="mc")
        for n in range(n_runs):
            r, az, el = meas[n][k]
            plot = RadarPlot(header=header, site_id=site_id, target_id=ids[n], range_m=r, az_deg=az, el_deg=el)
            est = None
            try:
                for out in core.step(plot):
                    if out.target_id == ids[n] and out.header.stamp_ns == stamp and out.status != "COASTING":
                        est = out
            except InputRejected:
                est = None
            recorders[n].add(est, truths[k], true_angles[k])
    result = aggregate([r.rec for r in recorders])
    result["rejected"] = dict(core.counters)
    result["config"] = config.model_dump(mode="json")
    return result
