"""The coordinator's input/output protocol, shared by the service and by simulations run without Zenoh.

:class:`CoordinatorProtocol` wraps :class:`~services.coordinator.core.CoordinatorCore` for one vehicle group: it
takes one uplink input (key and message: ``VehicleStatus``, ``AcousticArrival`` heard at the base, ``BeaconTable``),
runs the core and returns an :class:`Answer`: the decisions (``BeaconAssignment``, ``DepartureGrant``) and one
:class:`~schemas.rd_nav.CoordinatorReply` that names the input (key, source, seq) and repeats the decisions. The
service publishes both; the player plugin ``rd_group`` waits for the replies (over Zenoh) or asks a protocol
object in-process (``fixstream mc``, ``scenario_events``): the same function, two drivers, so a simulated group
gets the same decisions both ways (pure: no Zenoh, no wall clock).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

from schemas import AcousticArrival, BeaconTable, Header, Message
from schemas.rd_nav import BeaconAssignment, CoordinatorReply, DepartureGrant, VehicleStatus
from shared.errors import InputRejected

from .config import CoordinatorConfig
from .core import CoordinatorCore

#: the inputs of the coordinator (its uplink)
INPUTS: tuple[type[Message], ...] = (VehicleStatus, AcousticArrival, BeaconTable)


def config_digest(config: CoordinatorConfig) -> str:
    """16 hex digits identifying a coordinator configuration (a simulation warns when the service's differs)."""
    return hashlib.sha256(config.model_dump_json().encode()).hexdigest()[:16]


@dataclass
class Answer:
    """What one input gave: the decisions, the reply, and the refusal if the input was refused."""

    decisions: list[BeaconAssignment | DepartureGrant]
    reply: CoordinatorReply
    rejected: InputRejected | None = None
    alarms: dict[str, int] = field(default_factory=dict)  #: alarm counters that rose on this input


class CoordinatorProtocol:
    """One group's coordinator core behind the uplink/reply protocol."""

    def __init__(self, group: str, config: CoordinatorConfig | None = None) -> None:
        self.group = group
        self.config = config or CoordinatorConfig()
        self.digest = config_digest(self.config)
        self.core = CoordinatorCore(self.config)

    def reset(self) -> None:
        """A fresh core (a new scenario run starts from an empty registry)."""
        self.core = CoordinatorCore(self.config)

    def handle(self, key: str, msg: Message) -> Answer:
        """Run one input through the core. Never raises for bad input: the refusal is in the answer."""
        before = dict(self.core.alarms)
        rejected: InputRejected | None = None
        decisions: list[BeaconAssignment | DepartureGrant] = []
        try:
            if not isinstance(msg, INPUTS):
                allowed = ", ".join(m.__name__ for m in INPUTS)
                raise InputRejected("unexpected_type", f"{type(msg).__name__} on {key}; expects {allowed}")
            for out in self.core.step(msg):
                if isinstance(out, BeaconAssignment | DepartureGrant):
                    decisions.append(out)
        except InputRejected as exc:
            rejected = exc
        a = self.core.assignment
        reply = CoordinatorReply(
            header=Header(stamp_ns=msg.header.stamp_ns, frame_id=self.config.frame_id),
            group=self.group,
            input_key=key,
            input_source=msg.header.source,
            input_seq=msg.header.seq,
            rejected=rejected.reason if rejected is not None else None,
            assignments=[d for d in decisions if isinstance(d, BeaconAssignment)],
            grants=[d for d in decisions if isinstance(d, DepartureGrant)],
            epoch=a.epoch if a is not None else 0,
            config_digest=self.digest,
        )
        rose = {k: n - before.get(k, 0) for k, n in self.core.alarms.items() if n > before.get(k, 0)}
        return Answer(decisions, reply, rejected, rose)


__all__ = ["INPUTS", "Answer", "CoordinatorProtocol", "config_digest"]
