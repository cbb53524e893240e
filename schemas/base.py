"""Base message type, the common header and reusable field types.

Every stream in fixstream is a pydantic v2 model deriving from :class:`Message`. Models are strict
(no silent type coercion), frozen, reject unknown fields and reject NaN/inf in every float field.
Units are carried in field names (``_m``, ``_s``, ``_rad``, ``_deg``, ``_mps``) or descriptions.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field

#: registry of every concrete message model by schema name (filled by ``Message.__init_subclass__``)
MODELS: dict[str, type[Message]] = {}


class StrictModel(BaseModel):
    """Strict, frozen, closed pydantic model: the base of every payload and sub-record."""

    model_config = ConfigDict(strict=True, extra="forbid", allow_inf_nan=False, frozen=True)


#: latest time of validity a message may carry, ns: 2**62 ns is 146 years after the scenario clock's zero (or
#: the year 2116 on the Unix clock of recorded data), and the sum of two stamps still fits a signed 64-bit integer
MAX_STAMP_NS = 2**62
#: latest time of validity a service takes as INPUT, ns: one day below :data:`MAX_STAMP_NS`, so that every output
#: derived from an input (an epoch closed later, a prediction ahead) still has a valid stamp
STAMP_HEADROOM_NS = 86_400 * 10**9
MAX_INPUT_STAMP_NS = MAX_STAMP_NS - STAMP_HEADROOM_NS
#: largest per-publisher sequence number (a signed 64-bit integer, so msgpack, numpy and every reader hold it)
MAX_SEQ = 2**63 - 1


class Header(StrictModel):
    """Common header of every message (architecture rule 3)."""

    stamp_ns: int = Field(ge=0, le=MAX_STAMP_NS, description="time of validity of the data, ns on the scenario clock")
    frame_id: str = Field(default="", max_length=128, description="frame of the spatial quantities")
    source: str = Field(default="", max_length=256, description="publisher that produced the message")
    seq: int = Field(default=0, ge=0, le=MAX_SEQ, description="per-publisher sequence number, for loss counting")

    @property
    def stamp_s(self) -> float:
        return self.stamp_ns * 1e-9


class Message(StrictModel):
    """A top-level stream payload. Concrete subclasses register themselves in :data:`MODELS`."""

    schema_version: ClassVar[int] = 1
    header: Header

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if not cls.__name__.startswith("_"):
            MODELS[cls.__name__] = cls

    @classmethod
    def schema_id(cls) -> str:
        """Schema name and version as carried on the wire, e.g. ``fixstream.BeaconRange/1``."""
        return f"fixstream.{cls.__name__}/{cls.schema_version}"

    @property
    def stamp_ns(self) -> int:
        return self.header.stamp_ns


def _check_vec(n: int) -> Any:
    def check(v: list[float]) -> list[float]:
        if len(v) != n:
            raise ValueError(f"expected {n} components, got {len(v)}")
        return v

    return AfterValidator(check)


#: the largest magnitude of a vector component (positions, velocities, accelerations, angles; SI units): a million
#: km, beyond anything a sensor here measures. An unbounded component once let 1e300 in, whose square overflowed to
#: inf inside a filter and failed every later message of the run (``internal_error``)
VEC_COMPONENT_MAX = 1e9
#: one such component, also a coordinate given on its own (a beacon's east and north)
VecComponent = Annotated[float, Field(ge=-VEC_COMPONENT_MAX, le=VEC_COMPONENT_MAX)]

Vec2 = Annotated[list[VecComponent], _check_vec(2)]
Vec3 = Annotated[list[VecComponent], _check_vec(3)]


def _check_covariance(m: list[list[float]]) -> list[list[float]]:
    """Square, symmetric and positive semi-definite, to a tolerance relative to the largest entry.

    PSD is tested by a Cholesky factorisation of ``m + 1e-9·max|m|·I`` (cheaper than eigenvalues).
    """
    n = len(m)
    if n == 0 or any(len(row) != n for row in m):
        raise ValueError("covariance must be a non-empty square matrix")
    a = np.array(m, dtype=float)
    scale = float(np.abs(a).max()) or 1.0
    if float(np.abs(a - a.T).max()) > 1e-9 * scale:
        raise ValueError("covariance is not symmetric")
    try:
        np.linalg.cholesky(a + np.eye(n) * (1e-9 * scale))
    except np.linalg.LinAlgError:
        raise ValueError("covariance is not positive semi-definite") from None
    return m


Covariance = Annotated[list[list[float]], AfterValidator(_check_covariance)]

Sigma = Annotated[float, Field(gt=0.0, description="one-sigma standard deviation, > 0")]
