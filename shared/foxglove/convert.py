"""fixstream messages as Foxglove's well-known schemas: a 3D scene with covariance ellipsoids, and map fixes.

One converter for the recorder (extra MCAP channels) and the live bridge (``fixstream foxglove``), built on the
message classes of the ``foxglove-sdk`` package (``foxglove.messages``, protobuf-encoded, schemas named
``foxglove.<Name>``). For every message that carries positions (:func:`shared.foxglove.frames.estimates_of`:
truth, fixes, hypotheses, tracks — all brought into the scenario's ENU frame):

* ``/foxglove/scene/<key>`` — ``foxglove.SceneUpdate``: one entity per truth, fix, hypothesis or track
  (entity id = platform, target, ``track 12``, ``auv1/h2``; frame = the scenario's ``frame_id``) with a
  sphere at the position — for an estimate with a covariance, the **3σ ellipsoid**: axes along the
  covariance's eigenvectors (the pose's orientation), diameters 2·3·√λ (the size); for 2-D covariances the
  vertical axis is nominal — and a text label. A message with ``tracks`` (a PCL scan report) replaces its
  tracks and deletes the dropped ones;
* ``/foxglove/location/<key>`` — ``foxglove.LocationFix`` (truth and fixes of one platform) or
  ``foxglove.LocationFixes`` (``Track`` and the types a plugin lists in ``multi_views``: a scan's tracks):
  latitude, longitude and height of the ENU position from the scenario's geodetic ``origin``. The scenario
  frame is the topocentric Cartesian frame at the origin, and the conversion its exact inverse on WGS84
  (:class:`shared.geodesy.LocalFrame`, PROJ; the player converts recorded geodetic tracks into the frame with
  the same transform, so a recorded track shows where it was recorded). A simulated aircraft at constant "up"
  flies a straight line of that Cartesian frame, so its height above the ellipsoid grows with its distance from
  the origin (~785 m at 100 km). The ENU covariance goes with it (``Known``). Without an origin there is no map
  channel.

``<key>`` is the fixstream key without its ``fixstream/`` root (``/foxglove/scene/fix/terrain/tan1``).
Timestamps are the messages' ``header.stamp_ns`` (the scenario clock).

The frame context and origin come from the scenario, found when the player's start marker passes
(:meth:`Converter.on_marker`: the marker's name looked up in the scenarios directory, as ``fixstream play``
looks names up) or given at construction.
"""

from __future__ import annotations

import functools
import logging
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from schemas import Message, ScenarioMarker
from shared import keys
from shared.geodesy import LocalFrame
from shared.plugins import multi_view_types

from .frames import F64, Estimate, FrameContext, estimates_of

log = logging.getLogger("fixstream.foxglove")

SCENE_PREFIX = "/foxglove/scene/"
LOCATION_PREFIX = "/foxglove/location/"
#: the ellipsoids are drawn at this many sigmas
N_SIGMA = 3.0
#: generic messages with any number of positions: their map channel is ``foxglove.LocationFixes`` (else
#: ``LocationFix``); an estimator's own such types are its plugin's ``multi_views``
MULTI = frozenset({"Track"})
#: sphere diameter of a truth sample or an estimate without covariance, m
POINT_SIZE_M = 20.0


_COLORS: dict[str, tuple[float, float, float, float]] = {
    "truth": (0.1, 0.75, 0.2, 0.9),
    "fix": (0.15, 0.45, 0.95, 0.45),
    "hypothesis": (1.0, 0.55, 0.0, 0.45),
    "track": (0.6, 0.2, 0.8, 0.45),
    "tentative": (0.55, 0.55, 0.55, 0.35),
    "invalid": (0.9, 0.2, 0.2, 0.35),
}


@dataclass(frozen=True)
class Origin:
    """Geodetic origin of the scenario frame (WGS84)."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0

    @functools.cached_property
    def _frame(self) -> LocalFrame:
        return LocalFrame(self)

    def to_geodetic(self, enu: Sequence[float] | F64) -> tuple[float, float, float]:
        """(lat deg, lon deg, height m above the ellipsoid) of an ENU position of the scenario frame: the exact
        inverse of the topocentric frame at the origin (:mod:`shared.geodesy`)."""
        lat, lon, alt = self._frame.to_geodetic(np.asarray(enu, dtype=np.float64).reshape(1, 3))[0]
        return float(lat), float(lon), float(alt)


def ellipsoid(cov: F64, n_sigma: float = N_SIGMA) -> tuple[list[float], list[float]]:
    """(diameters along the principal axes [x, y, z], orientation quaternion [x, y, z, w]) of the n-σ ellipsoid.

    The axes are the eigenvectors of ``cov`` (a right-handed rotation), the diameters 2·n·√λ."""
    c = 0.5 * (np.asarray(cov, dtype=np.float64) + np.asarray(cov, dtype=np.float64).T)
    vals, vecs = np.linalg.eigh(c)
    vals = np.clip(vals, 0.0, None)
    if np.linalg.det(vecs) < 0:
        vecs[:, 2] = -vecs[:, 2]
    size = [float(2.0 * n_sigma * math.sqrt(v)) for v in vals]
    return size, quaternion(vecs)


def quaternion(rot: F64) -> list[float]:
    """[x, y, z, w] of a rotation matrix (columns: the rotated frame's axes)."""
    m = np.asarray(rot, dtype=np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        w, x, y, z = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        w, x, y, z = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        w, x, y, z = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s
    q = np.array([x, y, z, w])
    q /= np.linalg.norm(q)
    return [float(v) for v in q]


@dataclass(frozen=True)
class Converted:
    """One Foxglove message to log: topic and the ``foxglove.messages`` object (``.encode()``, ``get_schema()``)."""

    topic: str
    message: Any

    @property
    def schema_name(self) -> str:
        return str(type(self.message).get_schema().name)


#: the last stamp a Foxglove ``Timestamp`` holds (its seconds are a u32: 2106-02-07 on the UNIX clock), below the
#: schemas' 2**62 ns
FOXGLOVE_MAX_STAMP_NS = 2**32 * 1_000_000_000 - 1


def _timestamp(stamp_ns: int) -> Any:
    """A Foxglove ``Timestamp``; ``ValueError`` naming the range for a stamp beyond it (a message is then not drawn,
    and counted where it was converted; it was an ``OverflowError: number too large to fit in target type``)."""
    from foxglove.messages import Timestamp

    if not 0 <= stamp_ns <= FOXGLOVE_MAX_STAMP_NS:
        raise ValueError(f"stamp {stamp_ns} ns is outside Foxglove's time range (0 to 2^32 s)")
    return Timestamp(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)


def _color(e: Estimate) -> Any:
    from foxglove.messages import Color

    if e.kind == "track" and not e.valid:
        rgba = _COLORS["tentative"]
    elif e.kind == "fix" and not e.valid:
        rgba = _COLORS["invalid"]
    else:
        rgba = _COLORS[e.kind]
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _entity(e: Estimate, frame_id: str) -> Any:
    from foxglove.messages import KeyValuePair, Pose, Quaternion, SceneEntity, SpherePrimitive, TextPrimitive, Vector3

    p = e.position
    position = Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2]))
    if e.cov is not None and np.all(np.isfinite(e.cov)):
        size, q = ellipsoid(e.cov)
    else:
        size, q = [POINT_SIZE_M] * 3, [0.0, 0.0, 0.0, 1.0]
    sphere = SpherePrimitive(
        pose=Pose(position=position, orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])),
        size=Vector3(x=size[0], y=size[1], z=size[2]),
        color=_color(e),
    )
    text = TextPrimitive(
        pose=Pose(position=position, orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
        billboard=True,
        font_size=12.0,
        scale_invariant=True,
        color=_color(e),
        text=e.label or e.entity,
    )
    meta = [KeyValuePair(key="kind", value=e.kind), KeyValuePair(key="valid", value=str(e.valid).lower())]
    if e.cov is not None:
        meta.append(KeyValuePair(key="n_sigma", value=f"{N_SIGMA:g}"))
    return SceneEntity(
        timestamp=_timestamp(e.stamp_ns),
        frame_id=frame_id,
        id=e.entity,
        frame_locked=False,
        metadata=meta,
        spheres=[sphere],
        texts=[text],
    )


def _location(e: Estimate, origin: Origin) -> Any:
    from foxglove.messages import LocationFix, LocationFixPositionCovarianceType

    lat, lon, alt = origin.to_geodetic(e.position)
    kw: dict[str, Any] = {}
    if e.cov is not None:
        kw["position_covariance"] = [float(v) for v in np.asarray(e.cov, dtype=np.float64).reshape(-1)]
        kw["position_covariance_type"] = LocationFixPositionCovarianceType.Known
    else:
        kw["position_covariance_type"] = LocationFixPositionCovarianceType.Unknown
    return LocationFix(
        timestamp=_timestamp(e.stamp_ns), frame_id=e.entity, latitude=lat, longitude=lon, altitude=alt, **kw
    )


class Converter:
    """fixstream messages to Foxglove messages (see the module doc)."""

    def __init__(
        self,
        ctx: FrameContext | None = None,
        origin: Origin | None = None,
        scenarios_dir: str | os.PathLike[str] | None = None,
        scenario_loader: Callable[[str, Path | None], Any] | None = None,
    ) -> None:
        self.ctx = ctx or FrameContext()
        self.origin = origin
        self.scenarios_dir = Path(scenarios_dir) if scenarios_dir is not None else None
        #: (scenario name, scenarios directory) -> the Scenario, raising ValueError when there is none; given by
        #: the process that knows scenario files (the player's loader), so that this runtime module names no service
        self.scenario_loader = scenario_loader
        self._fixed = ctx is not None or origin is not None
        self.scenario_name: str | None = None

    @classmethod
    def for_scenario(cls, scenario: Any) -> Converter:
        """A converter for a :class:`services.player.scenario.Scenario` (its frames and ``origin``)."""
        o = getattr(scenario, "origin", None)
        origin = Origin(o.lat_deg, o.lon_deg, o.alt_m) if o is not None else None
        conv = cls(FrameContext.from_scenario(scenario), origin)
        conv.scenario_name = scenario.name
        return conv

    def on_marker(self, marker: ScenarioMarker) -> None:
        """A start marker: load its scenario's frames and origin (unless fixed at construction)."""
        if self._fixed or marker.event != "start" or marker.scenario == self.scenario_name:
            return
        self.scenario_name = marker.scenario
        try:
            if self.scenario_loader is None:
                raise ValueError("no scenario loader")
            scenario = self.scenario_loader(marker.scenario, self.scenarios_dir)
        except ValueError as exc:
            log.warning("foxglove: scenario %s not found (%s): default frames, no map channels", marker.scenario, exc)
            self.ctx, self.origin = FrameContext(), None
            return
        other = Converter.for_scenario(scenario)
        self.ctx, self.origin = other.ctx, other.origin
        log.info(
            "foxglove: scenario %s, frame %s, origin %s", scenario.name, self.ctx.scenario_frame, self.origin or "none"
        )

    def convert(self, key: str, msg: Message) -> list[Converted]:
        """The Foxglove messages of one fixstream message (empty if it carries no position)."""
        if isinstance(msg, ScenarioMarker):
            self.on_marker(msg)
            return []
        ests = estimates_of(key, msg, self.ctx)
        deleted = [t.track_id for t in getattr(msg, "tracks", ()) if getattr(t, "status", "") == "DROPPED"]
        if not ests and not deleted:
            return []
        from foxglove.messages import LocationFixes, SceneEntityDeletion, SceneEntityDeletionType, SceneUpdate

        rest = key.removeprefix(f"{keys.ROOT}/")
        frame = self.ctx.scenario_frame
        deletions = [
            SceneEntityDeletion(
                timestamp=_timestamp(msg.header.stamp_ns), type=SceneEntityDeletionType.MatchingId, id=f"track {tid}"
            )
            for tid in deleted
        ]
        out = [
            Converted(SCENE_PREFIX + rest, SceneUpdate(deletions=deletions, entities=[_entity(e, frame) for e in ests]))
        ]
        if self.origin is not None:
            located = [e for e in ests if e.kind in ("truth", "fix", "track")]
            name = type(msg).__name__
            if name in MULTI or name in multi_view_types():  # one schema per topic: these always as LocationFixes
                fixes = LocationFixes(fixes=[_location(e, self.origin) for e in located])
                out.append(Converted(LOCATION_PREFIX + rest, fixes))
            elif located:
                out.append(Converted(LOCATION_PREFIX + rest, _location(located[0], self.origin)))
        return out


__all__ = ["LOCATION_PREFIX", "N_SIGMA", "SCENE_PREFIX", "Converted", "Converter", "Origin", "ellipsoid", "quaternion"]
