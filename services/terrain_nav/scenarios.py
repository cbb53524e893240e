"""Named flight scenarios: the paper replica and each terrain type / failure case of the digest's §4.

All share the digest's common harness (:class:`FlightScenario` defaults): 200 x 101 cells of 125 m, start in
cell (70, 70), 200 m/s along +x, 20 Hz INS and RA, 51 x 51 hypotheses' stop rule, initial offset +-20 cells,
sigma_Vh 0.3 m/s, RA noise 2 m, map noise 3 m.
"""

from __future__ import annotations

from .simulation import FailureSpec, FlightScenario


def _failure(amp: float, onset_s: float = 6.0) -> tuple[FailureSpec, ...]:
    return (FailureSpec(kind="additive", onset_s=onset_s, duration_s=3.0, amplitude_m=amp),)


SCENARIOS: dict[str, FlightScenario] = {
    # §3.1: informative SRTM-like terrain, start (70, 70), an additive RA failure of several seconds with the
    # valid flag kept, inside the base algorithm's first N_min-cell profile (AT-1)
    "paper_replica": FlightScenario(name="paper_replica", failures=_failure(150.0)),
    "informative": FlightScenario(name="informative"),
    "flat": FlightScenario(name="flat", terrain="flat"),
    "ridge_x": FlightScenario(name="ridge_x", terrain="ridge_x"),
    "ridge_z": FlightScenario(name="ridge_z", terrain="ridge_z"),
    "periodic": FlightScenario(name="periodic", terrain="periodic"),
    "false_data_30m": FlightScenario(name="false_data_30m", failures=_failure(30.0, 25.0)),
    "false_data_80m": FlightScenario(name="false_data_80m", failures=_failure(80.0, 25.0)),
    "false_data_150m": FlightScenario(name="false_data_150m", failures=_failure(150.0, 25.0)),
    "recovery_400": FlightScenario(name="recovery_400", map_cells=(400, 101), failures=_failure(150.0, 30.0)),
    "dropouts": FlightScenario(
        name="dropouts",
        failures=(
            FailureSpec(kind="dropout", onset_s=12.0, duration_s=2.0),
            FailureSpec(kind="dropout", onset_s=37.0, duration_s=2.0),
        ),
        n_nan_samples=6,
    ),
    "out_of_zone": FlightScenario(name="out_of_zone", start_cell=(15, 50), offset_max_cells=3.0, duration_s=106.25),
    "velocity_error_0.5": FlightScenario(name="velocity_error_0.5", sigma_vh_mps=0.5),
    "velocity_error_1.0": FlightScenario(name="velocity_error_1.0", sigma_vh_mps=1.0),
    "velocity_error_2.0": FlightScenario(name="velocity_error_2.0", sigma_vh_mps=2.0),
    "ins_gap": FlightScenario(name="ins_gap", failures=(FailureSpec(kind="ins_gap", onset_s=30.0, duration_s=1.0),)),
}
