"""Positions and covariances of fixstream messages in one frame: the scenario's ENU frame.

Every estimator publishes in its own frame (``header.frame_id``); a person looking at a scene or a plan view
wants them all in one. :func:`estimates_of` turns a message into :class:`Estimate` s — position ``[east, north,
up]`` (m) in the scenario frame and, where the message has one, its 3x3 covariance in the same axes — using
:class:`FrameContext` for the frames it knows:

==========================  ======================================================  =============================
frame (``header.frame_id``)  axes of the message                                    to scenario ENU
==========================  ======================================================  =============================
the scenario's, ``*_enu``    east, north, up (``pcl_enu``: the receiver, at 0)       unchanged
``*_ned`` (``base_ned``)     north, east, down                                       [y, x, -z]
``local_en_depth``           east, north, depth                                      [x, y, -z]
``map`` (terrain_nav)        x north, z east, h up                                   [z, x, h]
``radar_nue/<site>``         north, up, east, radar-centred (attitude frame E)       site + [z, x, y]
anything else                taken as ENU                                            unchanged
==========================  ======================================================  =============================

The radar sites' positions come from the scenario's simulators whose parameters have a ``site_id`` and a
``site_position_m`` (attitude's radars); without a scenario they are taken at the origin. A covariance
transforms with the same axis permutation and signs.

Every fix and track carries its mean and covariance as a :class:`~schemas.estimate.GaussianEstimate` block;
:func:`gaussian_position` reads the position of any block by its frame and the names of the frame's axes
(``x``, ``y``, ``z``; ``x``, ``z``, ``h`` in ``map``): all three give a 3-D position, the two horizontal ones a
horizontal position whose vertical the caller supplies (value and variance; nominal variance by default).

The report (:mod:`tools.report`) plots these estimates against truth; the Foxglove conversion
(:mod:`shared.foxglove.convert`) draws them as scene entities and map fixes.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from schemas import Fix, Message, Track, Truth
from schemas.estimate import GaussianEstimate

from ..plugins import view_converter

F64 = NDArray[np.float64]
EstimateKind = Literal["truth", "fix", "hypothesis", "track"]

#: axis permutation and signs: enu[i] = sign[i] * vec[perm[i]]
_AXES: dict[str, tuple[tuple[int, int, int], tuple[float, float, float]]] = {
    "enu": ((0, 1, 2), (1.0, 1.0, 1.0)),
    "ned": ((1, 0, 2), (1.0, 1.0, -1.0)),
    "en_depth": ((0, 1, 2), (1.0, 1.0, -1.0)),
    "map": ((1, 0, 2), (1.0, 1.0, 1.0)),  # [x north, z east, h up]: enu = [z, x, h]
    "nue": ((2, 0, 1), (1.0, 1.0, 1.0)),  # [x north, y up, z east]: enu = [z, x, y]
}


#: names of a frame's position components in the frame's axis order, and the index of its vertical axis
_AXIS_NAMES: dict[str, tuple[tuple[str, str, str], int]] = {
    "enu": (("x", "y", "z"), 2),
    "ned": (("x", "y", "z"), 2),
    "en_depth": (("x", "y", "z"), 2),
    "map": (("x", "z", "h"), 2),
    "nue": (("x", "y", "z"), 1),
}


#: the offset of frames whose origin is the scenario's (compared by identity: the fast path of to_enu)
_ZERO = [0.0, 0.0, 0.0]


def frame_axes(frame_id: str) -> str:
    """The axes convention a frame id names (a key of the module table): ``enu`` for any frame it does not know.

    The scenario's own frame must be one this reads as ``enu``: its truth is east, north, up (the player's
    scenario validation refuses the others)."""
    if frame_id.startswith("radar_nue/"):
        return "nue"
    if frame_id == "map":
        return "map"
    if frame_id.endswith("_ned") or frame_id == "ned":
        return "ned"
    if frame_id.endswith("en_depth"):
        return "en_depth"
    return "enu"


@dataclass
class FrameContext:
    """What is needed to bring every frame into the scenario's ENU frame (see the module doc)."""

    scenario_frame: str = "local_enu"
    #: radar site id -> its position [east, north, up] in the scenario frame, m
    sites: dict[str, list[float]] = field(default_factory=dict)

    @classmethod
    def from_scenario(cls, scenario: Any | None) -> FrameContext:
        """Frames of a :class:`services.player.scenario.Scenario` (None: defaults)."""
        if scenario is None:
            return cls()
        sites: dict[str, list[float]] = {}
        for i, _ in enumerate(scenario.simulators):
            p = scenario.simulator_params(i)  # a radar site: any simulator with a site id and position
            site_id, pos = getattr(p, "site_id", None), getattr(p, "site_position_m", None)
            if isinstance(site_id, str) and pos is not None:
                sites[site_id] = [float(v) for v in pos]
        return cls(scenario_frame=scenario.frame_id, sites=sites)

    def axes(self, frame_id: str) -> tuple[str, list[float]]:
        """(axes convention, ENU offset of the frame's origin) of a frame id."""
        conv = frame_axes(frame_id)
        if conv == "nue":
            return conv, self.sites.get(frame_id.removeprefix("radar_nue/"), _ZERO)
        return conv, _ZERO

    def to_enu(self, vec: Iterable[float], frame_id: str, axes: str | None = None) -> F64:
        """A position in ``frame_id`` (or with the given axes convention, no offset) as scenario ENU."""
        conv, offset = (axes, _ZERO) if axes is not None else self.axes(frame_id)
        v = vec if isinstance(vec, list | tuple) else list(vec)
        if conv == "enu" and offset is _ZERO:
            return np.array(v, dtype=np.float64)
        perm, sign = _AXES[conv]
        return np.array([sign[0] * v[perm[0]], sign[1] * v[perm[1]], sign[2] * v[perm[2]]]) + np.asarray(offset)

    def to_enu_array(self, arr: F64, frame_id: str, axes: str | None = None) -> F64:
        """:meth:`to_enu` of every row of an (n, 3) array."""
        conv, offset = (axes, _ZERO) if axes is not None else self.axes(frame_id)
        perm, sign = _AXES[conv]
        a = np.asarray(arr, dtype=np.float64).reshape(-1, 3)
        return np.asarray(a[:, list(perm)] * np.asarray(sign) + np.asarray(offset), dtype=np.float64)

    def cov_to_enu(self, cov: F64, frame_id: str, axes: str | None = None) -> F64:
        """A 3x3 covariance in ``frame_id`` (or the given axes convention) in ENU axes."""
        conv = axes if axes is not None else self.axes(frame_id)[0]
        perm, sign = _AXES[conv]
        t = np.zeros((3, 3))
        for i in range(3):
            t[i, perm[i]] = sign[i]
        return np.asarray(t @ cov @ t.T, dtype=np.float64)


@dataclass(frozen=True)
class Estimate:
    """One position of a message in scenario ENU: a truth sample, a fix, a hypothesis or a track.

    ``entity`` names the thing within its key (platform, target, ``track 12``, ``auv1/h2``); ``platform`` is the
    truth platform it estimates when the message says so (None for tracks, which need association). ``cov`` is
    None when the message has no covariance; ``horizontal_only`` marks estimates whose vertical is not estimated
    (their vertical variance is a nominal value).
    """

    kind: EstimateKind
    entity: str
    platform: str | None
    stamp_ns: int
    position: F64
    cov: F64 | None = None
    valid: bool = True
    horizontal_only: bool = False
    label: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


#: vertical variance given to 2-D covariances so their ellipsoids have a visible thickness, m^2
NOMINAL_VERTICAL_VAR_M2 = 1.0


def gaussian_position(
    est: GaussianEstimate, ctx: FrameContext, vertical: tuple[float, float] | None = None
) -> tuple[F64, F64, bool] | None:
    """(position, 3x3 covariance, horizontal only) of a block in scenario ENU; None if it has no position.

    The position components are found by the names of the frame's axes (module doc). A block with the two
    horizontal ones only is placed at ``vertical`` = (value along the frame's vertical axis, its variance),
    by default (0, :data:`NOMINAL_VERTICAL_VAR_M2`); its covariance has no vertical cross terms."""
    conv, _ = ctx.axes(est.frame)
    names, iv = _AXIS_NAMES[conv]
    comps = est.components
    idx = [comps.index(n) if n in comps else -1 for n in names]
    m = est.mean
    if min(idx) >= 0:
        pos = ctx.to_enu([m[idx[0]], m[idx[1]], m[idx[2]]], est.frame)
        sub = np.asarray(est.covariance, dtype=np.float64)[np.ix_(idx, idx)]
        return pos, ctx.cov_to_enu(sub, est.frame), False
    hor = [i for k, i in enumerate(idx) if k != iv]
    if min(hor) < 0:
        return None
    v, var = vertical if vertical is not None else (0.0, NOMINAL_VERTICAL_VAR_M2)
    vec = [v, v, v]
    for k, i in enumerate(idx):
        if k != iv:
            vec[k] = m[i]
    pos = ctx.to_enu(vec, est.frame)
    # the horizontal 2x2 in ENU order (east, north) taken by index: no product, so no value is rounded or
    # given a signed zero; the horizontal axes of every frame keep their sign
    perm, _sign = _AXES[conv]
    c = np.asarray(est.covariance, dtype=np.float64)
    out = np.zeros((3, 3))
    src = [idx[perm[0]], idx[perm[1]]]
    out[np.ix_([0, 1], [0, 1])] = c[np.ix_(src, src)]
    out[2, 2] = var
    return pos, out, True


def estimates_of(key: str, msg: Message, ctx: FrameContext) -> list[Estimate]:
    """The positions a message carries, in scenario ENU (empty for messages that carry none).

    ``Truth`` and the generic ``Fix`` and ``Track`` are converted here; an estimator's own output types by the
    converter its plugin declares for the type name (``Plugin.views``, :func:`shared.plugins.view_converter`); any
    other message whose ``estimate`` is a Gaussian block with a position becomes one ``fix`` named after the last
    chunk of its key (its ``platform`` if it has one), valid unless its ``valid`` says otherwise."""
    name = type(msg).__name__
    fn = _truth if name == "Truth" else view_converter(name)
    if fn is not None:
        return fn(key, msg, ctx)
    if isinstance(msg, Fix):
        return _fix(key, msg, ctx)
    if isinstance(msg, Track):
        return _track(key, msg, ctx)
    block = getattr(msg, "estimate", None)
    if isinstance(block, GaussianEstimate):
        return _any_block(key, msg, block, ctx)
    return []


def _any_block(key: str, msg: Any, block: GaussianEstimate, ctx: FrameContext) -> list[Estimate]:
    got = gaussian_position(block, ctx)
    if got is None:
        return []
    platform = getattr(msg, "platform", None)
    entity = platform if isinstance(platform, str) else key.rsplit("/", 1)[-1]
    valid = getattr(msg, "valid", True) is not False
    stamp = msg.header.stamp_ns
    return [Estimate("fix", entity, entity, stamp, got[0], got[1], valid, got[2], label=type(msg).__name__)]


def _truth(key: str, msg: Any, ctx: FrameContext) -> list[Estimate]:
    assert isinstance(msg, Truth)
    pos = ctx.to_enu(msg.position_m, msg.header.frame_id)
    extra: dict[str, Any] = {}
    if msg.velocity_mps is not None:
        conv = ctx.axes(msg.header.frame_id)[0]
        extra["velocity"] = ctx.to_enu(msg.velocity_mps, msg.header.frame_id, axes=conv)
    if msg.attitude_rad is not None:
        extra["attitude_rad"] = list(msg.attitude_rad)
    return [Estimate("truth", msg.platform, msg.platform, msg.header.stamp_ns, pos, label=msg.platform, extra=extra)]


def _fix(key: str, msg: Any, ctx: FrameContext) -> list[Estimate]:
    out: list[Estimate] = []
    got = gaussian_position(msg.estimate, ctx)
    if got is not None:
        pos, cov, hor = got
        stamp = msg.header.stamp_ns
        out.append(Estimate("fix", msg.platform, msg.platform, stamp, pos, cov, msg.valid, hor, label=msg.status))
    out.extend(hypothesis_estimates(msg.platform, msg.header.stamp_ns, msg.hypotheses, ctx))
    return out


def hypothesis_estimates(
    platform: str, stamp_ns: int, hypotheses: Iterable[Any], ctx: FrameContext, valid: bool = True
) -> list[Estimate]:
    """The :class:`~schemas.outputs.Hypothesis` entries of a fix as ``hypothesis`` estimates."""
    out = []
    for h in hypotheses:
        got = gaussian_position(h.estimate, ctx)
        if got is None:
            continue
        out.append(
            Estimate(
                "hypothesis",
                f"{platform}/h{h.hypothesis_id}",
                platform,
                stamp_ns,
                got[0],
                got[1],
                valid,
                got[2],
                label=f"h{h.hypothesis_id} p={h.probability:.3f}",
                extra={"probability": h.probability, "hypothesis_id": h.hypothesis_id},
            )
        )
    return out


def _track(key: str, msg: Any, ctx: FrameContext) -> list[Estimate]:
    got = gaussian_position(msg.estimate, ctx)
    if got is None:
        return []
    ent = f"{msg.tracker}/{msg.track_id}"
    pos, cov, hor = got
    return [
        Estimate(
            "track",
            ent,
            None,
            msg.header.stamp_ns,
            pos,
            cov,
            msg.status != "DROPPED",
            hor,
            f"{msg.track_id} {msg.status}",
        )
    ]


__all__ = [
    "NOMINAL_VERTICAL_VAR_M2",
    "Estimate",
    "FrameContext",
    "estimates_of",
    "gaussian_position",
    "hypothesis_estimates",
]
