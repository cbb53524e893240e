"""Read a compose file into plain dataclasses: the subset of the Compose Specification that the local
runner needs (command, entrypoint, environment, env_file, depends_on, volumes, labels, working_dir,
profiles, stop_signal, stop_grace_period). Everything else (ports, networks, build, restart, ...) is
accepted and ignored, because it only matters to a container engine."""

from __future__ import annotations

import os
import re
import shlex
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from .interpolate import InterpolationError, interpolate_tree, parse_env_file

COMPOSE_FILENAMES = ("compose.yaml", "compose.yml", "docker-compose.yaml", "docker-compose.yml")
DRIVER_LABEL = "fixstream.role"
ALIVE_LABEL = "fixstream.alive"
ROUTER_IMAGE = re.compile(r"^(?:(?:docker\.io|index\.docker\.io)/)?eclipse/zenoh(?::[^/@]*)?(?:@sha256:[0-9a-f]+)?$")
_CONDITIONS = ("service_started", "service_healthy", "service_completed_successfully")


class ComposeError(ValueError):
    """The compose file cannot be run."""


@dataclass(frozen=True)
class Volume:
    """A mount: ``bind`` (source is an absolute host path) or ``volume`` (source is a name, or '' if anonymous)."""

    kind: str
    source: str
    target: str
    read_only: bool = False


@dataclass
class ServiceSpec:
    name: str
    image: str | None = None
    command: list[str] = field(default_factory=list)
    entrypoint: list[str] | None = None
    #: ``None`` values are passed through from the host environment, as compose does
    environment: dict[str, str | None] = field(default_factory=dict)
    env_files: list[Path] = field(default_factory=list)
    depends_on: dict[str, str] = field(default_factory=dict)
    volumes: list[Volume] = field(default_factory=list)
    labels: dict[str, str] = field(default_factory=dict)
    working_dir: str | None = None
    profiles: list[str] = field(default_factory=list)
    stop_signal: str | None = None
    stop_grace_period: float | None = None
    hostnames: tuple[str, ...] = ()

    @property
    def is_zenoh_router(self) -> bool:
        return bool(self.image and ROUTER_IMAGE.match(self.image))

    @property
    def is_driver(self) -> bool:
        return self.labels.get(DRIVER_LABEL) == "driver"


@dataclass
class ComposeProject:
    path: Path
    directory: Path
    services: dict[str, ServiceSpec]
    #: the variables interpolation used (``.env`` < process environment < overrides)
    variables: dict[str, str]
    warnings: list[str] = field(default_factory=list)

    def select(self, names: Iterable[str] = (), profiles: Iterable[str] = ()) -> list[str]:
        """Services to run, dependencies included, in start order (as ``compose up [SERVICE...]``)."""
        wanted = list(names)
        for name in wanted:
            if name not in self.services:
                raise ComposeError(f"no such service: {name}")
        active = set(profiles)
        if not wanted:
            wanted = [n for n, s in self.services.items() if not s.profiles or active & set(s.profiles)]
        chosen: set[str] = set()
        stack = list(wanted)
        while stack:
            name = stack.pop()
            if name not in chosen:
                chosen.add(name)
                stack.extend(self.services[name].depends_on)
        return [n for n in self.start_order() if n in chosen]

    def start_order(self) -> list[str]:
        """Topological order of depends_on; ties keep the file order."""
        order: list[str] = []
        state: dict[str, int] = {}

        def visit(name: str, trail: tuple[str, ...]) -> None:
            if state.get(name) == 2:
                return
            if state.get(name) == 1:
                raise ComposeError("dependency cycle: " + " -> ".join((*trail, name)))
            state[name] = 1
            for dep in self.services[name].depends_on:
                visit(dep, (*trail, name))
            state[name] = 2
            order.append(name)

        for name in self.services:
            visit(name, ())
        return order


def find_compose_file(start: Path) -> Path:
    """``compose.yaml`` (or its other names) in ``start`` or the nearest parent, like compose does."""
    for directory in (start.resolve(), *start.resolve().parents):
        for name in COMPOSE_FILENAMES:
            candidate = directory / name
            if candidate.is_file():
                return candidate
    raise ComposeError(f"no {' / '.join(COMPOSE_FILENAMES)} in {start} or its parents")


def interpolation_variables(
    directory: Path,
    env_file: Path | None = None,
    environ: Mapping[str, str] | None = None,
    overrides: Mapping[str, str] | None = None,
    warn: Callable[[str], None] | None = None,
) -> dict[str, str]:
    """``.env`` beside the compose file (or ``env_file``) < the process environment < ``overrides``."""
    env = dict(os.environ if environ is None else environ)
    dotenv_path = env_file if env_file is not None else directory / ".env"
    dotenv: dict[str, str] = {}
    if env_file is not None and not env_file.is_file():
        raise ComposeError(f"env file not found: {env_file}")
    if dotenv_path.is_file():
        dotenv = parse_env_file(dotenv_path, env, warn or (lambda _m: None))
    return {**dotenv, **env, **(overrides or {})}


def load_compose(
    path: Path,
    env_file: Path | None = None,
    environ: Mapping[str, str] | None = None,
    overrides: Mapping[str, str] | None = None,
) -> ComposeProject:
    """Parse, interpolate and normalise a compose file."""
    path = path.resolve()
    directory = path.parent
    warnings: list[str] = []
    try:
        variables = interpolation_variables(directory, env_file, environ, overrides, warnings.append)
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
        if not isinstance(raw, dict) or not isinstance(raw.get("services"), dict):
            raise ComposeError(f"{path}: expected a mapping with a 'services' mapping")
        data = interpolate_tree(raw, variables, warnings.append)
    except InterpolationError as exc:
        raise ComposeError(f"{path}: {exc}") from None
    except yaml.YAMLError as exc:
        raise ComposeError(f"{path}: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ComposeError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    services = {str(name): _service(str(name), body or {}, directory) for name, body in data["services"].items()}
    for spec in services.values():
        for dep in spec.depends_on:
            if dep not in services:
                raise ComposeError(f"service {spec.name} depends on undefined service {dep}")
    return ComposeProject(path, directory, services, variables, list(dict.fromkeys(warnings)))


# ----- normalisation of one service ---------------------------------------------------------------------
def _argv(value: Any, what: str) -> list[str]:
    if value is None:
        return []
    if isinstance(value, str):
        return shlex.split(value)
    if isinstance(value, list):
        return [_scalar(v) for v in value]
    raise ComposeError(f"{what}: expected a string or a list")


def _scalar(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def _mapping(value: Any, what: str, allow_none: bool) -> dict[str, str | None]:
    """A compose ``KEY: value`` mapping or ``["KEY=value", "KEY"]`` list."""
    if value is None:
        return {}
    out: dict[str, str | None] = {}
    if isinstance(value, dict):
        for k, v in value.items():
            out[str(k)] = None if v is None and allow_none else _scalar("" if v is None else v)
        return out
    if isinstance(value, list):
        for item in value:
            key, sep, val = str(item).partition("=")
            out[key] = val if sep else (None if allow_none else "")
        return out
    raise ComposeError(f"{what}: expected a mapping or a list")


def _depends_on(value: Any, name: str) -> dict[str, str]:
    if value is None:
        return {}
    if isinstance(value, list):
        return {str(d): "service_started" for d in value}
    if isinstance(value, dict):
        out: dict[str, str] = {}
        for dep, body in value.items():
            condition = str((body or {}).get("condition", "service_started"))
            if condition not in _CONDITIONS:
                raise ComposeError(f"service {name}: depends_on {dep}: unknown condition {condition!r}")
            out[str(dep)] = condition
        return out
    raise ComposeError(f"service {name}: depends_on must be a list or a mapping")


def _host_path(source: str, directory: Path) -> str:
    return str((directory / os.path.expanduser(source)).resolve())


def _is_path(source: str) -> bool:
    return source.startswith((".", "/", "~"))


def _volumes(value: Any, name: str, directory: Path) -> list[Volume]:
    out: list[Volume] = []
    for item in value or []:
        if isinstance(item, str):
            parts = item.split(":")
            if len(parts) == 1:
                out.append(Volume("volume", "", parts[0]))
                continue
            source, target = parts[0], parts[1]
            read_only = len(parts) > 2 and "ro" in parts[2].split(",")
        elif isinstance(item, dict):
            source = str(item.get("source", ""))
            target = str(item.get("target", ""))
            read_only = bool(item.get("read_only", False))
            if item.get("type", "volume") == "bind" and not _is_path(source):
                source = "./" + source
        else:
            raise ComposeError(f"service {name}: bad volume entry {item!r}")
        if not target.startswith("/"):
            raise ComposeError(f"service {name}: volume target must be an absolute path: {item!r}")
        if _is_path(source):
            out.append(Volume("bind", _host_path(source, directory), target.rstrip("/") or "/", read_only))
        else:
            out.append(Volume("volume", source, target.rstrip("/") or "/", read_only))
    return out


_DURATION = re.compile(r"(\d+(?:\.\d+)?)(us|ms|h|m|s)")
_UNIT_S = {"us": 1e-6, "ms": 1e-3, "s": 1.0, "m": 60.0, "h": 3600.0}


def parse_duration(value: Any) -> float:
    """Compose durations: ``10s``, ``1m30s``, ``500ms`` (a bare number is seconds)."""
    if isinstance(value, int | float):
        return float(value)
    text = str(value).strip()
    if re.fullmatch(r"\d+(?:\.\d+)?", text):
        return float(text)
    parts = _DURATION.findall(text)
    if not parts or "".join(n + u for n, u in parts) != text:
        raise ComposeError(f"bad duration {value!r}")
    return sum(float(n) * _UNIT_S[u] for n, u in parts)


def _env_files(value: Any, directory: Path) -> list[Path]:
    if value is None:
        return []
    items = value if isinstance(value, list) else [value]
    paths: list[Path] = []
    for item in items:
        raw = item.get("path") if isinstance(item, dict) else item
        paths.append((directory / str(raw)).resolve())
    return paths


def _service(name: str, body: dict[str, Any], directory: Path) -> ServiceSpec:
    if not isinstance(body, dict):
        raise ComposeError(f"service {name}: expected a mapping")
    labels = {k: v or "" for k, v in _mapping(body.get("labels"), f"service {name}: labels", False).items()}
    entrypoint = body.get("entrypoint")
    hostnames = tuple(dict.fromkeys(h for h in (name, body.get("container_name"), body.get("hostname")) if h))
    return ServiceSpec(
        name=name,
        image=str(body["image"]) if body.get("image") else None,
        command=_argv(body.get("command"), f"service {name}: command"),
        entrypoint=None if entrypoint is None else _argv(entrypoint, f"service {name}: entrypoint"),
        environment=_mapping(body.get("environment"), f"service {name}: environment", True),
        env_files=_env_files(body.get("env_file"), directory),
        depends_on=_depends_on(body.get("depends_on"), name),
        volumes=_volumes(body.get("volumes"), name, directory),
        labels=labels,
        working_dir=str(body["working_dir"]) if body.get("working_dir") else None,
        profiles=[str(p) for p in body.get("profiles") or []],
        stop_signal=str(body["stop_signal"]) if body.get("stop_signal") else None,
        stop_grace_period=parse_duration(body["stop_grace_period"]) if body.get("stop_grace_period") else None,
        hostnames=tuple(str(h) for h in hostnames),
    )
