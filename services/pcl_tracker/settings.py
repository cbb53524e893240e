"""One flat set of tracker parameters, derived from :class:`~.config.PclTrackerConfig` (digest 003 §5.1).

The nested configuration (``geometry``, ``measurement_defaults``, ``tracker``, ``limits``) is flattened into
one namespace (every field name is unique across the sections), keeping each field's type, default, bounds
and description, so the service's environment variables and the Monte-Carlo plugin's ``params`` cannot
drift from the core's defaults:

* :class:`PclTrackerSettings`: the service settings, one environment variable per parameter,
  ``FIXSTREAM_PCL_TRACKER_<NAME>`` (case-insensitive; ``FIXSTREAM_PCL_TRACKER_CONFIRM_M=3``,
  ``FIXSTREAM_PCL_TRACKER_TX_POSITION_ENU_M=[8000, 0, 300]``), plus the instance name and the
  service-only options (snapshot file);
* :data:`PclTrackerParams`: the same parameters as a strict pydantic model (``estimators[].params`` of a
  scenario), plus the Monte-Carlo metric options.

:func:`to_config` turns either into the core's :class:`~.config.PclTrackerConfig` (which checks the
cross-field rules, e.g. ``confirm_N >= confirm_M``).
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, cast

from pydantic import BaseModel, ConfigDict, Field, create_model
from pydantic.fields import FieldInfo
from pydantic_settings import SettingsConfigDict

from shared.settings import ServiceSettings

from .config import GeometryConfig, LimitsConfig, MeasurementDefaults, PclTrackerConfig, TrackerConfig

#: section of PclTrackerConfig -> its model
SECTIONS: dict[str, type[BaseModel]] = {
    "geometry": GeometryConfig,
    "measurement_defaults": MeasurementDefaults,
    "tracker": TrackerConfig,
    "limits": LimitsConfig,
}
#: nested fields that are not parameters (the UT scheme has a single allowed value)
_NOT_FLAT = {"ut"}
#: tuple fields become lists (YAML and JSON give lists; strict validation refuses a list for a tuple)
_TUPLES = {"tx_position_enu_m", "imm_q_m2s4", "imm_sojourn_s", "imm_mu0"}


def flat_fields() -> dict[str, tuple[Any, FieldInfo]]:
    """Every parameter of every section: name -> (annotation, field info with default and bounds)."""
    out: dict[str, tuple[Any, FieldInfo]] = {}
    for section, model in SECTIONS.items():
        for name, info in model.model_fields.items():
            if name in _NOT_FLAT:
                continue
            if name in out:
                raise RuntimeError(f"parameter {name!r} of {section} is defined twice")
            if name in _TUPLES:
                default = list(cast(tuple[float, ...], info.default))
                lo, hi = _length_bounds(info, len(default))
                vec = cast(
                    FieldInfo, Field(default=default, min_length=lo, max_length=hi, description=info.description)
                )
                out[name] = (list[float], vec)
            else:
                out[name] = (info.annotation, copy.deepcopy(info))
    return out


def _length_bounds(info: FieldInfo, n_default: int) -> tuple[int, int]:
    """(min_length, max_length) of a tuple field: its declared bounds, else exactly its default's length."""
    lo = next((int(m.min_length) for m in info.metadata if hasattr(m, "min_length")), n_default)
    hi = next((int(m.max_length) for m in info.metadata if hasattr(m, "max_length")), n_default)
    return lo, hi


def section_of(name: str) -> str:
    for section, model in SECTIONS.items():
        if name in model.model_fields:
            return section
    raise KeyError(name)


def to_config(flat: BaseModel) -> PclTrackerConfig:
    """The core configuration from a flat parameter model (settings or params).

    Only the parameters given explicitly (environment, file or ``params``) are passed on, so the ones left out
    take the defaults of the chosen ``preset``.
    """
    values = flat.model_dump()
    nested: dict[str, dict[str, Any]] = {section: {} for section in SECTIONS}
    for name in flat_fields():
        if name not in flat.model_fields_set:
            continue
        value = values[name]
        nested[section_of(name)][name] = tuple(value) if name in _TUPLES else value
    return PclTrackerConfig.model_validate(nested)


class PclTrackerSettingsBase(ServiceSettings):
    """Service-only settings; the tracker parameters are added from the core's config (see module doc)."""

    model_config = SettingsConfigDict(env_prefix="FIXSTREAM_PCL_TRACKER_", extra="ignore")

    snapshot_file: Path | None = Field(
        default=None,
        description="[D] crash-restart snapshot (JSON): restored at start if its configuration matches, "
        "written on stop and every snapshot_every_scans scans",
    )
    snapshot_every_scans: int = Field(default=0, ge=0, description="0: write the snapshot only on stop")


#: the service settings: FIXSTREAM_PCL_TRACKER_<NAME> for every tracker parameter, instance, snapshot options
PclTrackerSettings = cast(
    type[PclTrackerSettingsBase],
    create_model("PclTrackerSettings", __base__=PclTrackerSettingsBase, __module__=__name__, **flat_fields()),  # type: ignore[call-overload]
)


class PclTrackerParamsBase(BaseModel):
    """Monte-Carlo options (the tracker parameters are added from the core's config)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    ospa_c_m: float = Field(default=1000.0, gt=0.0, description="OSPA cut-off c, m")
    ospa_p: float = Field(default=2.0, ge=1.0, description="OSPA order p")
    match_distance_m: float = Field(
        default=1000.0, gt=0.0, description="a confirmed track farther than this from every target is unmatched, m"
    )
    targets: list[str] | None = Field(
        default=None,
        description="truth platforms that are targets of this pair; default: the targets of the scenario's "
        "pcl_tracker simulators for this receiver-illuminator pair",
    )


#: ``estimators[].params`` of a scenario for kind pcl_tracker (validated strictly by the scenario loader)
PclTrackerParams = cast(
    type[PclTrackerParamsBase],
    create_model("PclTrackerParams", __base__=PclTrackerParamsBase, __module__=__name__, **flat_fields()),  # type: ignore[call-overload]
)
