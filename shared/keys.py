"""The key-expression tree of fixstream (architecture rule 4), built in one place.

fixstream/sensor/<platform>/<kind>/<sensor_id>
fixstream/truth/<platform>
fixstream/fix/<estimator>/<platform>[/<sub>...]   (e.g. fix/attitude/<site>/<target>, fix/terrain_nav/<v>/verdict)
fixstream/track/<tracker>/<track_id>
fixstream/diag/<service>/<instance>
fixstream/status/<service>/<instance>      (queryable)
fixstream/alive/<service>/<instance>       (liveliness)
fixstream/scenario/<name>                  (player start/end markers)
"""

from __future__ import annotations

import re
from typing import Annotated

from pydantic import AfterValidator

ROOT = "fixstream"
_CHUNK = re.compile(r"^[A-Za-z0-9_.\-]+$")


def chunk(value: str) -> str:
    """Validate one key chunk: no '/', no wildcards, no '$', not empty."""
    if not _CHUNK.match(value):
        raise ValueError(f"invalid key chunk {value!r}: use letters, digits, '_', '-', '.'")
    return value


#: a settings or parameter field holding one key chunk (validated by :func:`chunk`)
def is_chunk(value: str) -> bool:
    """True if ``value`` is a valid key chunk (:func:`chunk` would accept it)."""
    return _CHUNK.match(value) is not None


Chunk = Annotated[str, AfterValidator(chunk)]


def _key(*parts: str) -> str:
    return "/".join([ROOT, *(chunk(p) for p in parts)])


def sensor(platform: str, kind: str, sensor_id: str) -> str:
    return _key("sensor", platform, kind, sensor_id)


def truth(platform: str) -> str:
    return _key("truth", platform)


def fix(estimator: str, platform: str, *sub: str) -> str:
    """An estimator's output for a platform, optionally below it (a target of a radar site, a verdict stream)."""
    return _key("fix", estimator, platform, *sub)


def track(tracker: str, *track_path: str) -> str:
    return _key("track", tracker, *track_path)


def diag(service: str, instance: str) -> str:
    return _key("diag", service, instance)


def status(service: str, instance: str) -> str:
    return _key("status", service, instance)


def alive(service: str, instance: str) -> str:
    return _key("alive", service, instance)


def scenario(name: str) -> str:
    return _key("scenario", name)


ALL = f"{ROOT}/**"
ALIVE_ALL = f"{ROOT}/alive/**"
STATUS_ALL = f"{ROOT}/status/**"


def parse_alive(key: str) -> tuple[str, str]:
    """``fixstream/alive/<service>/<instance>`` -> (service, instance)."""
    parts = key.split("/")
    if len(parts) != 4 or parts[0] != ROOT or parts[1] != "alive":
        raise ValueError(f"not a liveliness key: {key!r}")
    return parts[2], parts[3]
