"""Recordings made without Zenoh: a scenario's events and the services' offline outputs, written as the recorder
writes them. For the report's tests and benchmark, and to try the report on a scenario without running a stack.

* :func:`scenario_feed` — the player's start marker, the scenario's events (:func:`services.player.timeline.
  scenario_events`, run ``run`` of ``seed``) and its end marker, as (key, message);
* :func:`service_outputs` — what a compose service (``compose.yaml``, its environment as ``fixstream up`` gives
  it) publishes for a feed, through :meth:`shared.service.Service.run_offline` (the service's own decode,
  dispatch and stamping, so sources and seqs are the real ones);
* :func:`lbl_items` / :func:`rd_items` — the LBL and group-navigation cores on their own simulations (for
  recordings of those estimators before their services and player plugins exist);
* :func:`write_recording` — everything merged by stamp into MCAP with the recorder's writer, log time =
  ``t0_ns`` + stamp;
* :func:`with_attachments` — a copy of a recording with metadata records and attachments added, as the recorder
  writes them to make a file self-describing (the scenario YAML as ``scenario/<file>.yaml``, the run's
  ``fixstream.run`` metadata: docs/recorder.md).
"""

from __future__ import annotations

import heapq
import os
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from schemas import Header, Message, ScenarioMarker, Truth
from shared import keys
from tools.registry import load_service

Item = tuple[str, Message]
#: log time of stamp 0 in the recordings written here (2026-01-01T00:00:00Z)
T0_NS = 1_767_225_600 * 10**9


def scenario_feed(scenario: Any, seed: int | None = None, run: int | None = None) -> list[Item]:
    """Markers and events exactly as ``fixstream play [--run run]`` publishes them."""
    from services.player.timeline import marker, scenario_events

    seed = scenario.seed if seed is None else seed
    events = scenario_events(scenario, seed, run=run)
    key = keys.scenario(scenario.name)
    counts = Counter(ev.key for ev in events)
    last = max((ev.stamp_ns for ev in events), default=0)
    return [
        (key, marker(scenario, seed, "start", 0, 0)),
        *((ev.key, ev.msg) for ev in events),
        (key, marker(scenario, seed, "end", last, 1, published=dict(counts))),
    ]


@contextmanager
def _environment(env: dict[str, str]) -> Iterator[None]:
    saved = {k: v for k, v in os.environ.items() if k.startswith("FIXSTREAM_")}
    try:
        for k in saved:
            del os.environ[k]
        os.environ.update(env)
        yield
    finally:
        for k in [k for k in os.environ if k.startswith("FIXSTREAM_")]:
            del os.environ[k]
        os.environ.update(saved)


def service_outputs(
    compose_service: str,
    feed: Sequence[Item],
    compose_file: str | Path = "compose.yaml",
    env: dict[str, str] | None = None,
) -> list[Item]:
    """What the compose service publishes for the feed (its subscriptions' part of it), offline; ``env``
    overrides variables of the service's compose environment."""
    import zenoh

    from tools.stack import load_compose

    project = load_compose(Path(compose_file))
    spec = project.services[compose_service]
    command = list(spec.command or [])
    if len(command) < 3 or command[1] != "run":
        raise ValueError(f"compose service {compose_service} is not a `fixstream run <service>` service")
    service_env = {
        k: v for k, v in spec.environment.items() if k.startswith("FIXSTREAM_") and "ZENOH" not in k and v is not None
    }
    service_env.update(env or {})
    with _environment(service_env):
        svc = load_service(command[2])
    exprs = [zenoh.KeyExpr(s.key_expr) for s in svc.subscriptions()] + [zenoh.KeyExpr(f"{keys.ROOT}/scenario/**")]
    wanted = [(k, m) for k, m in feed if any(e.intersects(zenoh.KeyExpr(k)) for e in exprs)]
    return [(o.key, o.msg) for o in svc.run_offline(wanted)]


def _stamp(items: Iterable[Item], source: str) -> list[Item]:
    seq: Counter[str] = Counter()
    out = []
    for key, msg in items:
        header = msg.header.model_copy(update={"source": source, "seq": seq[key]})
        seq[key] += 1
        out.append((key, msg.model_copy(update={"header": header})))
    return out


def lbl_items(
    seed: int = 1, t_end_s: float | None = None, spec: str = "s2", offset_s: float = 0.0, platform: str | None = None
) -> list[Item]:
    """An LBL run (digest 000, spec ``s1``/``s2``, ending ``t_end_s`` after the launch point): the simulation's
    inputs and truth as the player would publish them, and the core's fixes and events as ``lbl_nav/<vehicle>``;
    stamps shifted so the run starts at ``offset_s``."""
    import dataclasses

    import numpy as np

    from services.lbl_nav import simulation
    from services.lbl_nav.core import LblNavCore
    from services.lbl_nav.offline import scenario_config
    from shared.errors import InputRejected

    sp = simulation.s1_spec() if spec == "s1" else simulation.s2_spec()
    if t_end_s is not None:
        sp = simulation.with_end(sp, t_end_s)
    if platform is not None:
        sp = dataclasses.replace(sp, platform=platform)
    sim = simulation.simulate(sp, np.random.default_rng(seed), seed)
    core = LblNavCore(scenario_config(sp.name, platform=sp.platform))
    platform = sp.platform
    shift = int(offset_s * 1e9) - int(sim.stamps_ns[0])
    inputs: list[Item] = []
    outputs: list[Item] = []
    for m in sim.messages:
        kind = type(m).__name__.lower()
        sensor = getattr(m, "beacon_id", "0")
        inputs.append((keys.sensor(platform, kind, keys.chunk(sensor)), m))
        try:
            produced = core.step(m)
        except InputRejected:
            continue
        outputs += [(_lbl_key(platform, o), o) for o in produced]
    outputs += [(_lbl_key(platform, o), o) for o in core.flush()]
    truth: list[Item] = [(keys.truth(platform), t) for t in sim.truth_messages()]
    return [
        *_shift(_stamp(inputs + truth, "player/default"), shift),
        *_shift(_stamp(outputs, f"lbl_nav/{platform}"), shift),
    ]


def _lbl_key(platform: str, msg: Message) -> str:
    return keys.fix("lbl", platform) if type(msg).__name__ == "LblFix" else keys.fix("lbl", platform, "event")


def rd_items(seed: int = 1, duration_s: float = 300.0, offset_s: float = 0.0) -> list[Item]:
    """A group-navigation run (digest 002, the fleet scenario with the coordinator core in the loop): truth as the
    player would publish it, each moving AUV's fixes as ``rd_nav/<auv>`` and the coordinator's assignments and
    grants as ``coordinator/group1``."""
    from services.coordinator.config import CoordinatorConfig
    from services.coordinator.core import CoordinatorCore
    from services.rd_nav import simulation
    from services.rd_nav.offline import run

    cfg = simulation.fleet(duration_s=duration_s)
    coord = CoordinatorCore(CoordinatorConfig())
    log = run(cfg, seed, coordinator=coord, keep_messages=True)
    shift = int(offset_s * 1e9)
    items: list[Item] = []
    for auv, a in log.auv.items():
        items += _stamp([(keys.fix("rd", auv), f) for f in a.pf_fixes], f"rd_nav/{auv}")
    items += _stamp([(_coordinator_key("group1", m), m) for m in log.coordinator_out], "coordinator/group1")
    # truth at every cycle fix (the run scores its fixes against it: rows t, x, y, qxx, qxy, qyy, true x, true y)
    truths: list[Item] = []
    for auv, a in log.auv.items():
        depth = log.sim.vehicles[auv].depth_m
        for row in a.pf:
            stamp = log.sim.stamp_ns(row[0])
            truth = Truth(
                header=Header(stamp_ns=stamp, frame_id="base_ned"), platform=auv, position_m=[row[6], row[7], depth]
            )
            truths.append((keys.truth(auv), truth))
    truths.sort(key=lambda kv: kv[1].header.stamp_ns)
    items += _stamp(truths, "player/default")
    return _shift(items, shift)


def _shift(items: list[Item], shift_ns: int) -> list[Item]:
    if shift_ns == 0:
        return items
    out = []
    for key, msg in items:
        update: dict[str, Any] = {
            "header": msg.header.model_copy(update={"stamp_ns": max(0, msg.header.stamp_ns + shift_ns)})
        }
        for name in ("launch_stamp_ns", "resolved_stamp_ns"):  # LblFix: stamps inside the payload
            value = getattr(msg, name, None)
            if isinstance(value, int):
                update[name] = max(0, value + shift_ns)
        out.append((key, msg.model_copy(update=update)))
    return out


def marker(
    name: str, event: str, stamp_ns: int, seq: int, seed: int = 0, frame_id: str = "local_enu"
) -> ScenarioMarker:
    return ScenarioMarker(
        header=Header(stamp_ns=stamp_ns, frame_id=frame_id, source="player/default", seq=seq),
        event="start" if event == "start" else "end",
        scenario=name,
        seed=seed,
    )


def write_recording(
    out_dir: str | Path, *streams: Sequence[Item], prefix: str = "offline", t0_ns: int = T0_NS, foxglove: Any = None
) -> list[Path]:
    """Merge the streams by stamp (stable: ties keep stream, then list, order) and write them with the
    recorder's writer (``foxglove``: an optional :class:`shared.foxglove.recording.FoxgloveChannels`)."""
    from services.recorder.writer import RotatingMcapWriter

    writer = RotatingMcapWriter(Path(out_dir), prefix=prefix, rotate_size_bytes=0)
    keyed = [[(m.header.stamp_ns, i, j, k, m) for j, (k, m) in enumerate(s)] for i, s in enumerate(streams)]
    for stamp, _, _, key, msg in heapq.merge(*(sorted(s, key=lambda x: (x[0], x[2])) for s in keyed)):
        writer.write(key, msg, t0_ns + stamp)
        if foxglove is not None:
            foxglove.write(writer, key, msg, t0_ns + stamp)
    writer.finish()
    return list(writer.files_written)


def with_attachments(
    src: str | Path,
    dst: str | Path,
    attachments: Sequence[tuple[str, str, bytes]] = (),
    metadata: dict[str, dict[str, str]] | None = None,
) -> Path:
    """A copy of the MCAP ``src`` at ``dst`` (every schema, channel and message as it was) with ``metadata``
    (record name -> key/value) and ``attachments`` ((name, media type, data)) added, chunked and finalised."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    out = Path(dst)
    with Path(src).open("rb") as f, out.open("wb") as g:
        reader = make_reader(f)
        writer = Writer(g, compression=CompressionType.ZSTD)
        writer.start(profile="", library="fixstream offline")
        for record, values in (metadata or {}).items():
            writer.add_metadata(record, dict(values))
        for name, media_type, blob in attachments:
            writer.add_attachment(create_time=0, log_time=0, name=name, data=blob, media_type=media_type)
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.id not in channels:
                sid = 0
                if schema is not None:
                    if schema.id not in schemas:
                        schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
                    sid = schemas[schema.id]
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, sid, dict(channel.metadata)
                )
            writer.add_message(
                channels[channel.id], message.log_time, message.data, message.publish_time, message.sequence
            )
        writer.finish()
    return out


def scenario_attachment(path: str | Path) -> tuple[str, str, bytes]:
    """The scenario file as the recorder attaches it: ``scenario/<file name>``, ``application/yaml``."""
    p = Path(path)
    return (f"scenario/{p.name}", "application/yaml", p.read_bytes())


__all__ = [
    "T0_NS",
    "lbl_items",
    "marker",
    "rd_items",
    "scenario_attachment",
    "scenario_feed",
    "service_outputs",
    "with_attachments",
    "write_recording",
]


def _coordinator_key(group: str, msg: Message) -> str:
    """Where the coordinator service publishes ``msg`` (services/coordinator/service.py)."""
    from schemas.rd_nav import DepartureGrant
    from services.coordinator.service import assignment_key, grant_key

    return grant_key(group, msg.auv_id) if isinstance(msg, DepartureGrant) else assignment_key(group)
