"""Turn a compose project into local processes: the same commands, an embedded router, loopback endpoints.

* A service whose image is ``eclipse/zenoh[:tag]`` becomes ``fixstream router --listen
  tcp/127.0.0.1:<port>``: the port asked for (``--router-port``, else ``$FIXSTREAM_ROUTER_PORT``; busy is an
  error), else 7447 when it is free, else a free one (its ``--connect`` endpoints to other routers are rewritten
  too).
* Every other service runs its ``entrypoint + command`` locally: ``fixstream`` is this interpreter's
  ``python -m tools.cli.main`` and ``python``/``python3`` is this interpreter.
* Endpoints ``<proto>/<router host>:<container port>`` in environment values and arguments become the
  loopback router, and ``FIXSTREAM_ZENOH_CONNECT`` defaults to it.
* Container paths under a bind volume's target become the host path (created if missing); named and
  anonymous volumes become temporary directories.
* A recorder (``fixstream run recorder``, ``fixstream record``) is told to list the files it wrote
  (``FIXSTREAM_RECORDER_FILES_LIST``): the run's recordings are those, not whatever else appeared in the folder.
"""

from __future__ import annotations

import os
import re
import signal
import sys
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from shared import local_stack
from shared.session import free_tcp_port, port_free

from .compose import ALIVE_LABEL, ComposeError, ComposeProject, ServiceSpec, Volume
from .interpolate import parse_env_file
from .pki import IDENTITIES, ROUTER_ACL, Pki

FIXSTREAM_ARGV = [sys.executable, "-m", "tools.cli.main"]
PYTHON_NAMES = {"python", "python3", f"python{sys.version_info.major}.{sys.version_info.minor}"}
DEFAULT_ROUTER_PORT = 7447
#: interpolation variable with the router port compose publishes on the host
ROUTER_PORT_VAR = "FIXSTREAM_ROUTER_PORT"
DEFAULT_STOP_TIMEOUT = 10.0
#: the recorder setting (services/recorder/settings.py) the runner sets to learn which files its recorder wrote
RECORDER_FILES_LIST_VAR = "FIXSTREAM_RECORDER_FILES_LIST"
_ENDPOINT = re.compile(r"^(?P<proto>[a-z0-9]+)/(?P<host>\[[^\]]*\]|[^:/]+):(?P<port>\d+)")


@dataclass
class ProcessSpec:
    """One local process standing in for one compose service."""

    service: str
    argv: list[str]
    env: dict[str, str]
    cwd: Path
    depends_on: dict[str, str] = field(default_factory=dict)
    driver: bool = False
    router_port: int | None = None
    #: liveliness key expression that means "ready" (None: ready once started)
    ready_key: str | None = None
    stop_signal: int = signal.SIGTERM
    stop_timeout: float = 10.0
    #: a recorder's list of the MCAP files it wrote (``FIXSTREAM_RECORDER_FILES_LIST``, in a temporary directory)
    files_list: Path | None = None
    #: a ``fixstream run`` service: it answers the status query (what the runner waits on before stopping the stack)
    answers_status: bool = False


@dataclass
class StackPlan:
    project: ComposeProject
    processes: list[ProcessSpec]
    #: the loopback endpoint of the first embedded router (what the runner itself connects to)
    endpoint: str | None
    #: host directories of writable mounts (where recordings land)
    output_dirs: list[Path]
    temp_dirs: list[Path]
    #: the secure stack's client identity as ZenohSettings fields (tls_root_ca, tls_cert, tls_key); {} when open
    client_tls: dict[str, Path] = field(default_factory=dict)


def _listen_ports(argv: list[str]) -> list[int]:
    ports: list[int] = []
    for i, arg in enumerate(argv):
        value = None
        if arg in ("-l", "--listen") and i + 1 < len(argv):
            value = argv[i + 1]
        elif arg.startswith("--listen="):
            value = arg.split("=", 1)[1]
        if value:
            m = _ENDPOINT.match(value)
            if m:
                ports.append(int(m.group("port")))
    return ports or [DEFAULT_ROUTER_PORT]


def _connects(argv: list[str]) -> list[str]:
    out: list[str] = []
    for i, arg in enumerate(argv):
        if arg in ("-e", "--connect") and i + 1 < len(argv):
            out.append(argv[i + 1])
        elif arg.startswith("--connect="):
            out.append(arg.split("=", 1)[1])
    return out


class _Rewriter:
    """Rewrites router endpoints to loopback and container paths to host paths in one string."""

    def __init__(
        self, endpoints: Mapping[tuple[str, int], int], mounts: list[tuple[str, str]], proto: str = "tcp"
    ) -> None:
        self.endpoints = endpoints
        self.mounts = sorted(mounts, key=lambda m: len(m[0]), reverse=True)
        self.proto = proto

    def endpoint(self, value: str) -> str:
        def sub(m: re.Match[str]) -> str:
            local = self.endpoints.get((m.group("host"), int(m.group("port"))))
            return m.group(0) if local is None else f"{self.proto}/127.0.0.1:{local}"

        pattern = r"(?P<proto>[a-z0-9]+)/(?P<host>[A-Za-z0-9_.\-]+):(?P<port>\d+)"
        return re.sub(pattern, sub, value)

    def path(self, value: str) -> str:
        for target, host in self.mounts:
            if value == target:
                return host
            if value.startswith(target + "/"):
                return host + value[len(target) :]
        return value

    def __call__(self, value: str) -> str:
        value = self.endpoint(value)
        key, sep, rest = value.partition("=")
        if sep and not key.startswith("/") and rest.startswith("/"):
            return key + sep + self.path(rest)
        return self.path(value)


def _mount_dirs(
    spec: ServiceSpec, named: dict[str, Path], temp_dirs: list[Path], create: bool
) -> list[tuple[str, str]]:
    mounts: list[tuple[str, str]] = []
    for vol in spec.volumes:
        if vol.kind == "bind":
            host = Path(vol.source)
            if create and not host.exists():
                host.mkdir(parents=True, exist_ok=True)
        else:
            key = vol.source or f"{spec.name}:{vol.target}"
            if key not in named:
                prefix = f"fixstream-{re.sub(r'[^A-Za-z0-9_.-]', '_', key)}-"
                named[key] = Path(tempfile.mkdtemp(prefix=prefix)) if create else Path(tempfile.gettempdir(), prefix)
                if create:
                    temp_dirs.append(named[key])
            host = named[key]
        mounts.append((vol.target, str(host)))
    return mounts


def _service_args(argv: list[str]) -> list[str]:
    """The arguments after ``fixstream`` when ``argv`` runs the fixstream CLI, else []."""
    return argv[len(FIXSTREAM_ARGV) :] if argv[: len(FIXSTREAM_ARGV)] == FIXSTREAM_ARGV else []


def _runs_service(argv: list[str]) -> bool:
    """Whether ``argv`` is ``fixstream run <service> ...``."""
    args = _service_args(argv)
    return "run" in args and args.index("run") + 1 < len(args)


def _ready_key(spec: ServiceSpec, argv: list[str], env: Mapping[str, str]) -> str | None:
    if ALIVE_LABEL in spec.labels:
        return spec.labels[ALIVE_LABEL] or None
    if _runs_service(argv):
        args = _service_args(argv)
        name = args[args.index("run") + 1]
        instance = env.get(f"FIXSTREAM_{name.upper()}_INSTANCE") or env.get("FIXSTREAM_INSTANCE") or "*"
        return f"fixstream/alive/{name}/{instance}"
    return None


def _signal(name: str | None) -> int:
    if not name:
        return signal.SIGTERM
    text = name.upper()
    try:
        return int(signal.Signals[text if text.startswith("SIG") else "SIG" + text])
    except KeyError:
        raise ComposeError(f"unknown stop_signal {name!r}") from None


def _stop_timeout(spec: ServiceSpec, override: float | None) -> float:
    if override is not None:
        return override
    return spec.stop_grace_period if spec.stop_grace_period is not None else DEFAULT_STOP_TIMEOUT


def _local_argv(argv: list[str]) -> list[str]:
    if not argv:
        return argv
    if argv[0] == "fixstream":
        return [*FIXSTREAM_ARGV, *argv[1:]]
    if argv[0] in PYTHON_NAMES:
        return [sys.executable, *argv[1:]]
    return argv


def _router_port(project: ComposeProject, requested: int | None) -> int:
    """The first router's loopback port: ``requested`` (0: any free port), else ``$FIXSTREAM_ROUTER_PORT``,
    else the port compose publishes by default (7447), so that clients attach with no flags. A port asked for
    (``requested`` or the variable) must be free: a busy one is a :class:`ComposeError`, never replaced in
    silence (clients given that port would find no router). Only the default falls back to a free port (the
    runner says where, and announces it for clients: shared.local_stack)."""
    if requested is not None:
        port, source = requested, "--router-port"
    elif project.variables.get(ROUTER_PORT_VAR):
        text = project.variables[ROUTER_PORT_VAR].strip()
        if not text.isdigit():
            raise ComposeError(f"${ROUTER_PORT_VAR}={text!r} is not a port number (1-65535)")
        port, source = int(text), f"${ROUTER_PORT_VAR}"
    else:
        # also skip the port of a stack announced but whose router is not listening yet (two stacks started at once)
        claimed = any(s.endpoint.endswith(f":{DEFAULT_ROUTER_PORT}") for s in local_stack.running_stacks())
        return DEFAULT_ROUTER_PORT if not claimed and port_free(DEFAULT_ROUTER_PORT) else free_tcp_port()
    if not 0 <= port <= 65535:
        raise ComposeError(f"{source} {port} is not a port number (1-65535; 0: any free port)")
    if port == 0:
        return free_tcp_port()
    if not port_free(port):
        raise ComposeError(
            f"{source} {port}: the port is in use on 127.0.0.1 (another router or stack?); free it, choose another"
            " port, or give 0 for any free port"
        )
    return port


def plan_stack(
    project: ComposeProject,
    services: list[str],
    stop_timeout: float | None = None,
    environ: Mapping[str, str] | None = None,
    create_dirs: bool = True,
    router_port: int | None = None,
    secure: Pki | None = None,
) -> StackPlan:
    """Local processes for ``services`` (already in start order, e.g. from ``project.select``).

    ``stop_timeout`` overrides every service's ``stop_grace_period`` (default 10 s, as compose).
    ``create_dirs``: create missing bind sources and temporary directories for named volumes.
    ``router_port``: the embedded router's port (None: ``$FIXSTREAM_ROUTER_PORT``, else 7447 if free, see
    :func:`_router_port`; 0: any free port).
    ``secure``: the stack runs over mutual TLS with these certificates, every process with the identity of its
    role (:func:`identity_of`), and the router applies the repository's access control (:data:`ROUTER_ACL`)."""
    proto = "tls" if secure is not None else "tcp"
    base_env = dict(os.environ if environ is None else environ)
    specs = [project.services[name] for name in services]
    endpoints: dict[tuple[str, int], int] = {}
    router_ports: dict[str, int] = {}
    for spec in specs:
        if spec.is_zenoh_router:
            router_ports[spec.name] = _router_port(project, router_port) if not router_ports else free_tcp_port()
            for port in _listen_ports(spec.command):
                for host in spec.hostnames:
                    endpoints[(host, port)] = router_ports[spec.name]
    endpoint = f"{proto}/127.0.0.1:{next(iter(router_ports.values()))}" if router_ports else None

    named: dict[str, Path] = {}
    temp_dirs: list[Path] = []
    output_dirs: list[Path] = []
    processes: list[ProcessSpec] = []
    for spec in specs:
        mounts = _mount_dirs(spec, named, temp_dirs, create_dirs)
        output_dirs += [Path(h) for (t, h), v in zip(mounts, spec.volumes, strict=True) if not v.read_only]
        rewrite = _Rewriter(endpoints, mounts, proto)
        env = {k: v for k, v in base_env.items() if not (endpoint and k.startswith("FIXSTREAM_ZENOH_"))}
        env["PYTHONUNBUFFERED"] = "1"
        if endpoint and not spec.is_zenoh_router:
            env.update({"FIXSTREAM_ZENOH_MODE": "client", "FIXSTREAM_ZENOH_CONNECT": endpoint})
        for path in spec.env_files:
            if not path.is_file():
                raise ComposeError(f"service {spec.name}: env_file not found: {path}")
            env.update({k: rewrite(v) for k, v in parse_env_file(path, project.variables).items()})
        for key, value in spec.environment.items():
            if value is not None:
                env[key] = rewrite(value)
            elif key in base_env:
                env[key] = base_env[key]
        if spec.is_zenoh_router:
            port = router_ports[spec.name]
            argv = [*FIXSTREAM_ARGV, "router", "--listen", f"{proto}/127.0.0.1:{port}"]
            for peer in _connects(spec.command):
                argv += ["--connect", rewrite.endpoint(peer)]
            if secure is not None:
                argv += ["--config", str(ROUTER_ACL)]
        else:
            argv = _local_argv([rewrite(a) for a in [*(spec.entrypoint or []), *spec.command]])
            if not argv:
                raise ComposeError(f"service {spec.name}: no command (the local runner needs one)")
        if secure is not None:
            ident = secure.identity("router" if spec.is_zenoh_router else identity_of(argv))
            env.update(
                {
                    "FIXSTREAM_ZENOH_TLS_ROOT_CA": str(secure.ca),
                    "FIXSTREAM_ZENOH_TLS_CERT": str(ident.cert),
                    "FIXSTREAM_ZENOH_TLS_KEY": str(ident.key),
                }
            )
        files_list = None
        if not spec.is_zenoh_router and identity_of(argv) == "recorder" and RECORDER_FILES_LIST_VAR not in env:
            # what this run's recorder wrote, told by the recorder itself: a second stack writing into the same
            # directory at the same time does not make its files ours
            files_dir = Path(tempfile.gettempdir())
            if create_dirs:
                files_dir = Path(tempfile.mkdtemp(prefix="fixstream-files-"))
                temp_dirs.append(files_dir)
            files_list = files_dir / f"{spec.name}.files"
            env[RECORDER_FILES_LIST_VAR] = str(files_list)
        cwd = Path(rewrite.path(spec.working_dir)) if spec.working_dir else project.directory
        if not cwd.is_dir():
            cwd = project.directory
        processes.append(
            ProcessSpec(
                service=spec.name,
                argv=argv,
                env=env,
                cwd=cwd,
                depends_on=dict(spec.depends_on),
                driver=spec.is_driver,
                router_port=router_ports.get(spec.name),
                ready_key=None if spec.is_zenoh_router else _ready_key(spec, argv, env),
                stop_signal=_signal(spec.stop_signal),
                stop_timeout=_stop_timeout(spec, stop_timeout),
                files_list=files_list,
                answers_status=_runs_service(argv),
            )
        )
    client_tls: dict[str, Path] = {}
    if secure is not None:
        client = secure.identity("client")
        client_tls = {"tls_root_ca": secure.ca, "tls_cert": client.cert, "tls_key": client.key}
    return StackPlan(project, processes, endpoint, list(dict.fromkeys(output_dirs)), temp_dirs, client_tls)


def identity_of(argv: list[str]) -> str:
    """The secure stack's identity of a process, by what it runs: ``fixstream run <name>`` is ``<name>`` (an
    identity the router knows), ``fixstream play`` the player, ``fixstream record`` the recorder, anything
    else a read-only client."""
    args = argv[len(FIXSTREAM_ARGV) :] if argv[: len(FIXSTREAM_ARGV)] == FIXSTREAM_ARGV else []
    args = [a for a in args if not a.startswith("-")]
    if len(args) >= 2 and args[0] == "run" and args[1] in IDENTITIES:
        return args[1]
    return {"play": "player", "record": "recorder"}.get(args[0] if args else "", "client")


__all__ = ["FIXSTREAM_ARGV", "ProcessSpec", "StackPlan", "Volume", "plan_stack"]
