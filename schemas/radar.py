"""Radar streams: monostatic plots (attitude estimator) and bistatic PCL scans (tracker)."""

from __future__ import annotations

from pydantic import Field, model_validator

from .base import Message, StrictModel, Vec3

SPEED_OF_LIGHT_MPS = 299_792_458.0


class RadarSite(Message):
    """Radar site description and its measurement-error standard deviations."""

    site_id: str = Field(min_length=1, max_length=64)
    lat_deg: float = Field(ge=-90.0, le=90.0)
    lon_deg: float = Field(ge=-180.0, le=180.0)
    h_m: float = Field(ge=-500.0, le=10_000.0)
    sigma_r_m: float = Field(gt=0.0)
    sigma_az_deg: float = Field(gt=0.0, le=180.0)
    sigma_el_deg: float = Field(gt=0.0, le=90.0)
    scan_period_s: float = Field(gt=0.0, le=3_600.0)


class RadarPlot(Message):
    """A single monostatic radar look at a target (range, azimuth, elevation)."""

    site_id: str = Field(min_length=1, max_length=64)
    target_id: str = Field(min_length=1, max_length=64)
    range_m: float = Field(gt=0.0, le=2.0e6, description="slant range, m")
    az_deg: float = Field(ge=-720.0, le=720.0, description="clockwise from north; normalised mod 360")
    el_deg: float = Field(gt=-90.0, lt=90.0, description="above the radar's horizontal plane")
    sigma_r_m: float | None = Field(default=None, gt=0.0)
    sigma_az_deg: float | None = Field(default=None, gt=0.0)
    sigma_el_deg: float | None = Field(default=None, gt=0.0)


class TrackEnd(Message):
    """The radar retired a target id."""

    site_id: str = Field(min_length=1, max_length=64)
    target_id: str = Field(min_length=1, max_length=64)


class BistaticPlot(StrictModel):
    """One PCL plot. Exactly one range form and exactly one velocity form must be given."""

    plot_id: str = Field(min_length=1, max_length=64)
    azimuth_deg: float = Field(description="clockwise from north, any value (wrapped by the consumer)")
    elevation_deg: float = Field(ge=-90.0, le=90.0)
    bistatic_range_m: float | None = Field(default=None, description="r_b = R_rx + R_tx - L")
    range_sum_m: float | None = Field(default=None, description="R_rx + R_tx")
    delay_s: float | None = Field(default=None, description="r_b / c")
    bistatic_velocity_mps: float | None = Field(default=None, description="d r_b / dt")
    doppler_hz: float | None = None
    sigma_rb_m: float | None = None
    sigma_az_deg: float | None = None
    sigma_el_deg: float | None = None
    sigma_vb_mps: float | None = None
    snr_db: float | None = None

    @model_validator(mode="after")
    def _one_of_each(self) -> BistaticPlot:
        ranges = [self.bistatic_range_m, self.range_sum_m, self.delay_s]
        if sum(r is not None for r in ranges) != 1:
            raise ValueError("exactly one of bistatic_range_m, range_sum_m, delay_s must be given")
        if (self.bistatic_velocity_mps is None) == (self.doppler_hz is None):
            raise ValueError("exactly one of bistatic_velocity_mps, doppler_hz must be given")
        return self


class BistaticScan(Message):
    """All plots of one scan of one receiver-illuminator pair (empty scans are sent too)."""

    receiver_id: str = Field(min_length=1, max_length=64)
    illuminator_id: str = Field(min_length=1, max_length=64)
    scan_id: int = Field(ge=0, le=2**62)
    plots: list[BistaticPlot] = Field(max_length=100_000)


class BistaticConfigUpdate(Message):
    """Change of a receiver-illuminator pair's geometry (resets its tracks)."""

    receiver_id: str = Field(min_length=1, max_length=64)
    illuminator_id: str = Field(min_length=1, max_length=64)
    tx_position_enu_m: Vec3 = Field(description="transmitter relative to the receiver, ENU, m")
    wavelength_m: float | None = Field(default=None, gt=0.0)
