"""The one Gaussian estimate block every fix and track embeds (issue 19, item 6: one output vocabulary).

A :class:`GaussianEstimate` is a mean and its covariance with what is needed to read them without knowing the
message type: the frame the components are in (a frame id as ``header.frame_id`` uses them: ``map``,
``local_en_depth``, ``pcl_enu``, ``base_ned``, ``radar_nue/<site>``; ``shared/foxglove/frames.py`` maps each to
the scenario's ENU), the name and unit of every component. Position components are named after the frame's
axes (``x``, ``y``, ``z``; the terrain map frame's ``x``, ``z``, ``h``) so a reader finds them by name; the
other components (velocities, error states, bistatic coordinates) are the estimator's own, documented on the
field that holds the block. Each message field holding a block fixes its :class:`Layout` (component names and
units, in order) with :func:`block_field`: the layout is written into the field's JSON Schema (``x-components``,
``x-units``) and checked on validation (:func:`check_blocks`); the frame is the publisher's (its configuration).
The helper :func:`shared.estimates.gaussian` builds every block.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import Annotated, Any

from pydantic import BaseModel, Field, model_validator

from .base import Covariance, StrictModel

#: largest state a block carries (attitude's 9-state constant-acceleration filter is the largest published)
MAX_COMPONENTS = 16

_Name = Annotated[str, Field(min_length=1, max_length=32)]


class GaussianEstimate(StrictModel):
    """A Gaussian estimate: ``mean`` and ``covariance`` of the named ``components`` in ``frame``, in ``units``."""

    frame: str = Field(max_length=128, description="frame id of the components (as header.frame_id names frames)")
    components: list[_Name] = Field(
        min_length=1, max_length=MAX_COMPONENTS, description="name of each component, e.g. x, y, z, vx"
    )
    units: list[_Name] = Field(min_length=1, max_length=MAX_COMPONENTS, description="unit of each component, e.g. m")
    mean: list[float] = Field(min_length=1, max_length=MAX_COMPONENTS)
    covariance: Covariance = Field(description="n x n, in the products of the components' units")

    @model_validator(mode="after")
    def _shapes(self) -> GaussianEstimate:
        n = len(self.mean)
        if len(self.components) != n or len(self.units) != n or len(self.covariance) != n:
            raise ValueError("components, units, mean and covariance must have one entry (row) per component")
        return self

    def index(self, name: str) -> int:
        """Position of the component ``name`` (ValueError if the block has none)."""
        return self.components.index(name)


@dataclass(frozen=True)
class Layout:
    """Names and units of the components of a block, in order."""

    components: tuple[str, ...]
    units: tuple[str, ...]

    def __post_init__(self) -> None:
        if len(self.components) != len(self.units) or not 0 < len(self.units) <= MAX_COMPONENTS:
            raise ValueError("one unit per component, 1 to MAX_COMPONENTS of them")


#: a position in a frame whose axes are x, y, z (ENU, NED, east-north-depth, radar NUE)
POSITION = Layout(("x", "y", "z"), ("m", "m", "m"))
#: a horizontal position in such a frame (x, y)
HORIZONTAL = Layout(("x", "y"), ("m", "m"))
#: a velocity in such a frame
VELOCITY = Layout(("vx", "vy", "vz"), ("m/s", "m/s", "m/s"))
#: a constant-velocity Cartesian state
CV_STATE = Layout(("x", "y", "z", "vx", "vy", "vz"), ("m", "m", "m", "m/s", "m/s", "m/s"))

_LAYOUT_KEYS = ("x-components", "x-units")


def block_field(layout: Layout, description: str, optional: bool = False) -> Any:
    """A pydantic ``Field`` for a block of ``layout`` (default None if ``optional``), the layout in its schema."""
    extra: dict[str, Any] = {"x-components": list(layout.components), "x-units": list(layout.units)}
    if optional:
        return Field(default=None, description=description, json_schema_extra=extra)
    return Field(description=description, json_schema_extra=extra)


@cache
def _layouts(cls: type[BaseModel]) -> tuple[tuple[str, list[str], list[str]], ...]:
    out: list[tuple[str, list[str], list[str]]] = []
    for name, info in cls.model_fields.items():
        extra = info.json_schema_extra
        if isinstance(extra, dict) and _LAYOUT_KEYS[0] in extra:
            comps, units = extra[_LAYOUT_KEYS[0]], extra[_LAYOUT_KEYS[1]]
            assert isinstance(comps, list) and isinstance(units, list)
            out.append((name, [str(c) for c in comps], [str(u) for u in units]))
    return tuple(out)


def check_blocks(model: BaseModel) -> None:
    """Raise unless every block of ``model`` has the layout its field declares (a model validator calls this)."""
    for name, components, units in _layouts(type(model)):
        block = getattr(model, name)
        if block is not None and (block.components != components or block.units != units):
            raise ValueError(
                f"{name}: components {block.components} in {block.units}, expected {components} in {units}"
            )
