"""One valid example of every attitude-estimator model (digest 004), built by hand, not by the core."""

from __future__ import annotations

from schemas import Header, Message
from schemas.attitude import AttitudeEstimate, RawAttitudeAngles
from schemas.estimate import GaussianEstimate

H = Header(stamp_ns=1_700_000_000_123_456_789, frame_id="radar_nue/r1", source="attitude/r1", seq=7)
P9 = [[float(i == j) * (100.0 if i % 3 == 0 else 1.0 if i % 3 == 1 else 0.01) for j in range(9)] for i in range(9)]
P9[0][1] = P9[1][0] = 5.0
COV_LOS = [[4.0, 0.5, -0.2], [0.5, 3.0, 0.1], [-0.2, 0.1, 2.5]]

EXAMPLES: dict[str, Message] = {
    "AttitudeEstimate": AttitudeEstimate(
        header=H,
        site_id="r1",
        target_id="t17",
        status="VALID",
        n_updates=41,
        los_x="radar_to_target",
        gamma_los_form="paper",
        psi_deg=220.5,
        theta_deg=0.4,
        gamma_deg=-1.2,
        sigma_psi_deg=2.6,
        sigma_theta_deg=2.4,
        sigma_gamma_deg=1.1,
        psi_los_deg=147.9,
        theta_los_deg=3.5,
        gamma_los_deg=0.8,
        gamma_los_euler_deg=-2.1,
        sigma_psi_los_deg=2.7,
        sigma_theta_los_deg=2.5,
        sigma_gamma_los_deg=1.6,
        sigma_gamma_los_euler_deg=1.3,
        angle_cov_los_deg2=COV_LOS,
        aspect_az_deg=32.0,
        aspect_el_deg=-4.4,
        aspect_total_deg=32.3,
        sigma_aspect_az_deg=2.6,
        sigma_aspect_el_deg=2.3,
        sigma_aspect_total_deg=2.5,
        range_m=63_970.0,
        az_deg=72.39,
        el_deg=4.48,
        estimate=GaussianEstimate(
            frame=H.frame_id,
            components=["x", "vx", "ax", "y", "vy", "ay", "z", "vz", "az"],
            units=["m", "m/s", "m/s^2", "m", "m/s", "m/s^2", "m", "m/s", "m/s^2"],
            mean=[19295.6, -153.2, 0.01, 5000.0, 0.1, 0.0, 60782.7, -128.6, -0.02],
            covariance=P9,
        ),
        speed_mps=200.0,
        turn_rate_dps=0.01,
        load_factor=1.0,
        nis=2.7,
        model_probabilities=[0.9, 0.06, 0.04],
        flags=[],
        raw=RawAttitudeAngles(psi_deg=250.0, theta_deg=-12.0, gamma_deg=40.0, psi_los_deg=170.0, theta_los_deg=-9.0),
    ),
}
