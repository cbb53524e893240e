"""Real containers for the tests (and ``make images``): podman, Debian's docker-compose on podman's
Docker-compatible socket, and images built where no registry image can be pulled.

* The base image: ``debootstrap`` of the machine's own Debian release from its configured Debian source,
  imported with ``podman import`` as ``localhost/fixstream-base:<suite>-<key>``. The key is a hash of what goes
  into it (suite, source, variant, packages), so it is built once per machine and reused after that.
* The project image: the repository's ``Dockerfile`` built on that base (``--build-arg BASE_IMAGE``), with the
  host's CA bundle as the build secret ``pip_cert`` (pip reaches PyPI through this machine's proxy). Tagged
  ``localhost/fixstream:ctx-<key>``, the key a hash of the base image and every file the build copies, so an
  unchanged tree builds nothing; a changed one rebuilds from the first changed layer (buildah's layer cache:
  the locked dependencies are rebuilt only when ``Dockerfile`` or ``requirements.lock`` change).
* ``podman system service`` on a private socket for docker-compose (``DOCKER_HOST``), and a healthcheck driver:
  podman runs healthchecks from systemd timers, so on a machine without systemd a container's health stays
  ``starting`` for ever and ``depends_on: condition: service_healthy`` never starts. The driver runs
  ``podman healthcheck run`` for the compose project's containers that are still starting, as the timer would.

``python tests/container_support.py images`` builds both images and tags the project image ``fixstream:latest``;
``python tests/container_support.py demo`` (``make demo-containers``) then runs the demo stack as containers with
every step above done for the user, the recording in ``./recordings`` owned by whoever ran it.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
#: what the Dockerfile copies (besides Dockerfile itself); .dockerignore keeps caches out of these
CONTEXT = (
    "Dockerfile",
    "requirements.lock",
    "pyproject.toml",
    "README.md",
    "schemas",
    "shared",
    "services",
    "tools",
    "scenarios",
)
_IGNORED = re.compile(r"(^|/)(__pycache__|\.mypy_cache|\.pytest_cache|[^/]*\.egg-info)(/|$)|\.py[co]$|\.mcap$")
BASE_PACKAGES = ("python3", "python3-venv", "ca-certificates")
DEFAULT_MIRROR = "http://deb.debian.org/debian"


def run(argv: Sequence[str], timeout: float = 600.0, **kw: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(list(argv), capture_output=True, text=True, timeout=timeout, check=False, **kw)  # type: ignore[call-overload,no-any-return]


def _first_line(text: str) -> str:
    return next((ln.strip() for ln in text.splitlines() if ln.strip()), "no output")


def engine_problem() -> str | None:
    """Why containers cannot run here (one line), or None. ``make tools`` installs what is missing."""
    for tool, package in (("podman", "podman"), ("docker-compose", "docker-compose")):
        if shutil.which(tool) is None:
            return f"{tool} not installed (`make tools` installs the Debian package {package})"
    if not any(Path(p).exists() for p in ("/usr/bin/catatonit", "/usr/libexec/podman/catatonit")):
        return "catatonit not installed (`make tools`): compose's `init: true` needs it under podman"
    info = run(["podman", "info", "--format", "{{.Host.OCIRuntime.Name}}"], timeout=60)
    if info.returncode != 0:
        return f"podman cannot run here: {_first_line(info.stderr)}"
    if os.environ.get("FIXSTREAM_TEST_BASE_IMAGE") is None:
        if shutil.which("debootstrap") is None and not Path("/usr/sbin/debootstrap").exists():
            return "debootstrap not installed (`make tools`): it builds the base image"
        if os.geteuid() != 0:
            return "building the base image (debootstrap) needs root; or set FIXSTREAM_TEST_BASE_IMAGE to a base image"
    return None


# ----- the base image ---------------------------------------------------------------------------------------------
def debian_suite() -> str:
    """This machine's Debian codename (VERSION_CODENAME of /etc/os-release)."""
    text = Path("/etc/os-release").read_text()
    m = re.search(r"^VERSION_CODENAME=\"?([a-z]+)", text, re.M)
    if m is None:
        raise RuntimeError("no VERSION_CODENAME in /etc/os-release: not a Debian-like machine")
    return m.group(1)


def debian_mirror(suite: str, apt_dir: Path = Path("/etc/apt")) -> str:
    """The URI of the configured Debian source that serves ``suite`` with ``main`` (deb822 ``.sources`` or
    one-line ``.list`` files), else deb.debian.org."""
    files = [apt_dir / "sources.list", *sorted((apt_dir / "sources.list.d").glob("*"))]
    for path in files:
        if not path.is_file():
            continue
        text = path.read_text(errors="replace")
        if path.suffix == ".sources":
            for stanza in re.split(r"\n\s*\n", text):
                fields = dict(re.findall(r"^([A-Za-z-]+):[ \t]*(.*)$", stanza, re.M))
                if (
                    "deb" in fields.get("Types", "").split()
                    and suite in fields.get("Suites", "").split()
                    and "main" in fields.get("Components", "").split()
                    and fields.get("Enabled", "yes").lower() != "no"
                ):
                    return fields["URIs"].split()[0].rstrip("/")
        elif path.suffix == ".list" or path.name == "sources.list":
            for line in text.splitlines():
                words = re.sub(r"\[[^\]]*\]", "", line.split("#", 1)[0]).split()
                if len(words) >= 4 and words[0] == "deb" and words[2] == suite and "main" in words[3:]:
                    return words[1].rstrip("/")
    return DEFAULT_MIRROR


def _image_exists(ref: str) -> bool:
    return run(["podman", "image", "exists", ref], timeout=60).returncode == 0


def base_image(log: list[str] | None = None) -> str:
    """The Debian base image (built with debootstrap unless a tag with the same key exists), or
    ``$FIXSTREAM_TEST_BASE_IMAGE`` (e.g. ``docker.io/library/python:3.11-slim`` where it can be pulled)."""
    forced = os.environ.get("FIXSTREAM_TEST_BASE_IMAGE")
    if forced:
        return forced
    suite = debian_suite()
    mirror = debian_mirror(suite)
    recipe = {"suite": suite, "mirror": mirror, "variant": "minbase", "include": BASE_PACKAGES, "format": 1}
    key = hashlib.sha256(json.dumps(recipe, sort_keys=True).encode()).hexdigest()[:12]
    tag = f"localhost/fixstream-base:{suite}-{key}"
    if _image_exists(tag):
        return tag
    debootstrap = shutil.which("debootstrap") or "/usr/sbin/debootstrap"
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="fixstream-base-", dir="/var/tmp") as tmp:
        root = Path(tmp) / "rootfs"
        argv = [debootstrap, "--variant=minbase", f"--include={','.join(BASE_PACKAGES)}", suite, str(root), mirror]
        proc = run(argv, timeout=1200)
        if proc.returncode != 0:
            tail = "\n".join((proc.stdout + proc.stderr).splitlines()[-15:])
            raise RuntimeError(f"debootstrap {suite} from {mirror} failed:\n{tail}")
        for junk in ("var/cache/apt/archives", "var/lib/apt/lists"):
            for f in (root / junk).glob("*"):
                if f.is_file():
                    f.unlink()
        tar = subprocess.Popen(["tar", "-C", str(root), "-c", "."], stdout=subprocess.PIPE)
        imp = run(["podman", "import", "--change", 'CMD ["/bin/bash"]', "-", tag], stdin=tar.stdout, timeout=600)
        assert tar.stdout is not None
        tar.stdout.close()
        tar.wait()
        if imp.returncode != 0 or tar.returncode != 0:
            raise RuntimeError(f"podman import failed: {_first_line(imp.stderr)}")
    run(["podman", "tag", tag, f"localhost/fixstream-base:{suite}"])
    if log is not None:
        log.append(f"built base image {tag} from {mirror} in {time.monotonic() - t0:.0f} s")
    return tag


# ----- the project image ------------------------------------------------------------------------------------------
def context_files(repo: Path = REPO) -> list[Path]:
    """Every file the Dockerfile's COPY instructions take from the build context (caches excluded)."""
    out: list[Path] = []
    for name in CONTEXT:
        path = repo / name
        if path.is_file():
            out.append(path)
            continue
        for sub in sorted(path.rglob("*")):
            rel = sub.relative_to(repo).as_posix()
            if sub.is_file() and not _IGNORED.search(rel):
                out.append(sub)
    return out


def context_key(base: str, repo: Path = REPO) -> str:
    """Hash of the base image's id and the path, mode and content of every context file."""
    h = hashlib.sha256()
    image_id = run(["podman", "image", "inspect", "--format", "{{.Id}}", base], timeout=60).stdout.strip()
    h.update(f"base {base} {image_id}\n".encode())
    for f in context_files(repo):
        h.update(f"{f.relative_to(repo).as_posix()} {f.stat().st_mode & 0o111}\n".encode())
        h.update(hashlib.sha256(f.read_bytes()).digest())
    return h.hexdigest()[:16]


def ca_bundle() -> str | None:
    for candidate in (
        os.environ.get("PIP_CERT"),
        os.environ.get("SSL_CERT_FILE"),
        "/etc/ssl/certs/ca-certificates.crt",
    ):
        if candidate and Path(candidate).is_file():
            return candidate
    return None


def project_image(base: str, log: list[str] | None = None, also_tag: Sequence[str] = ()) -> str:
    """``localhost/fixstream:ctx-<key>``, built from the repository's Dockerfile on ``base`` if missing."""
    tag = f"localhost/fixstream:ctx-{context_key(base)}"
    if not _image_exists(tag):
        t0 = time.monotonic()
        argv = ["podman", "build", "--build-arg", f"BASE_IMAGE={base}", "-t", tag]
        cert = ca_bundle()
        if cert:
            argv += ["--secret", f"id=pip_cert,src={cert}"]
        proc = run([*argv, str(REPO)], timeout=1800)
        if proc.returncode != 0:
            tail = "\n".join((proc.stdout + proc.stderr).splitlines()[-25:])
            raise RuntimeError(f"podman build failed:\n{tail}")
        if log is not None:
            log.append(f"built {tag} in {time.monotonic() - t0:.0f} s")
        _prune_old_context_tags(keep=tag)
    for extra in also_tag:
        run(["podman", "tag", tag, extra])
    return tag


def _prune_old_context_tags(keep: str, max_age_s: float = 86_400.0) -> None:
    """Untag ``fixstream:ctx-*`` images older than a day (their layers go once nothing uses them)."""
    proc = run(["podman", "images", "--format", "json", "localhost/fixstream"], timeout=60)
    with contextlib.suppress(ValueError):
        for image in json.loads(proc.stdout or "[]"):
            names = [n for n in image.get("Names") or [] if ":ctx-" in n and n != keep]
            if names and time.time() - float(image.get("Created", time.time())) > max_age_s:
                run(["podman", "rmi", *names], timeout=120)


# ----- running compose on podman ----------------------------------------------------------------------------------
@contextlib.contextmanager
def docker_api() -> Iterator[str]:
    """``podman system service`` on a private socket for the duration; yields its ``DOCKER_HOST``."""
    tmp = Path(tempfile.mkdtemp(prefix="fs-podman-"))
    sock = tmp / "podman.sock"
    with (tmp / "service.log").open("w") as log:
        proc = subprocess.Popen(
            ["podman", "system", "service", "--time=0", f"unix://{sock}"], stdout=log, stderr=subprocess.STDOUT
        )
    try:
        deadline = time.monotonic() + 30
        while not sock.exists():
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"podman system service did not start: {(tmp / 'service.log').read_text()[-500:]}")
            time.sleep(0.05)
        yield f"unix://{sock}"
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
        shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def healthcheck_driver(project: str, interval_s: float = 0.5) -> Iterator[None]:
    """Run the healthchecks of ``project``'s starting containers every ``interval_s`` (see the module docstring).

    Stops polling once every container that had a healthcheck is past ``starting`` (``podman ps`` costs CPU)."""
    stop = threading.Event()

    def loop() -> None:
        seen = False
        while not stop.wait(interval_s):
            ids = run(
                [
                    "podman",
                    "ps",
                    "-q",
                    "--filter",
                    f"label=com.docker.compose.project={project}",
                    "--filter",
                    "health=starting",
                ],
                timeout=60,
            ).stdout.split()
            for cid in ids:
                seen = True
                run(["podman", "healthcheck", "run", cid], timeout=60)
            if seen and not ids:
                return

    thread = threading.Thread(target=loop, name=f"healthchecks-{project}", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(timeout=60)


def compose_up(
    project: str,
    files: Sequence[Path],
    env: Mapping[str, str],
    docker_host: str,
    timeout_s: float = 600.0,
    services: Sequence[str] = (),
    exit_codes: dict[str, int | None] | None = None,
) -> subprocess.CompletedProcess[str]:
    """``docker-compose up --no-build --exit-code-from player`` on podman, then ``down`` whatever happened.

    ``exit_codes``: filled, before the ``down``, with the exit code of each service it names (None: no container or
    no code). ``--exit-code-from`` returns the player's code only: a recorder that exited 1 (a write error) is
    seen here."""
    full_env = {**env, "DOCKER_HOST": docker_host}
    base = ["docker-compose", "-p", project, *(a for f in files for a in ("-f", str(f)))]
    try:
        with healthcheck_driver(project):
            return run(
                [*base, "up", "--no-build", "--no-color", "--exit-code-from", "player", *services],
                timeout=timeout_s,
                env=full_env,
                cwd=REPO,
            )
    finally:
        for name in exit_codes or {}:
            assert exit_codes is not None
            exit_codes[name] = _exit_code(base, name, full_env)
        run([*base, "down", "--remove-orphans", "--timeout", "5"], timeout=300, env=full_env, cwd=REPO)


def container_id(base: Sequence[str], service: str, env: Mapping[str, str]) -> str | None:
    """The id of ``service``'s (first) container of the compose project ``base`` names, or None."""
    ids = run([*base, "ps", "-q", service], timeout=120, env=env, cwd=REPO).stdout.split()
    return ids[0] if ids else None


def inspect(cid: str, fmt: str) -> str:
    """``podman inspect --format fmt`` of a container (e.g. ``{{.State.Pid}}``), stripped."""
    return run(["podman", "inspect", "--format", fmt, cid], timeout=60).stdout.strip()


def crash(cid: str) -> tuple[int, int]:
    """SIGKILL the init of a running container from the host (a crash: the engine's restart policy applies, as it
    does not to ``podman kill`` or ``stop``). Returns its (pid, restart count) before the kill."""
    pid, restarts = (int(v) for v in inspect(cid, "{{.State.Pid}} {{.RestartCount}}").split())
    assert pid > 0, f"container {cid} is not running"  # os.kill(0, ...) would kill this process group
    os.kill(pid, signal.SIGKILL)
    return pid, restarts


def restarted(cid: str, pid: int, restarts: int) -> bool:
    """Whether a container :func:`crash` killed (``pid``, ``restarts`` before) runs again as a new process."""
    state = inspect(cid, "{{.State.Status}} {{.State.Pid}} {{.RestartCount}}").split()
    return len(state) == 3 and state[0] == "running" and int(state[1]) not in (0, pid) and int(state[2]) > restarts


def _exit_code(base: Sequence[str], service: str, env: Mapping[str, str]) -> int | None:
    """The exit code of ``service``'s (first) container of the compose project ``base`` names, or None."""
    cid = container_id(base, service, env)
    if cid is None:
        return None
    code = inspect(cid, "{{.State.ExitCode}}")
    return int(code) if code.lstrip("-").isdigit() else None


def demo(recordings: Path) -> int:
    """The demo stack as containers on podman (``compose.yaml`` + the router override): the Docker API socket, the
    healthcheck driver and a recordings directory the containers can write, done here so that a user need not.
    The services run as the calling user (``FIXSTREAM_UID``/``FIXSTREAM_GID``, unless set), so the MCAP file
    belongs to whoever ran the demo. Returns compose's exit code (the player's), or 1 when the player's was 0 but no
    recording appeared or the recorder exited non-zero."""
    recordings.mkdir(parents=True, exist_ok=True)
    env = {
        **os.environ,
        "FIXSTREAM_UID": os.environ.get("FIXSTREAM_UID", str(os.getuid())),
        "FIXSTREAM_GID": os.environ.get("FIXSTREAM_GID", str(os.getgid())),
        "FIXSTREAM_RECORDINGS": str(recordings.resolve()),
    }
    before = set(recordings.glob("*.mcap"))
    files = (REPO / "compose.yaml", REPO / "compose.fixstream-router.yaml")
    codes: dict[str, int | None] = {"recorder": None}
    with docker_api() as host:
        proc = compose_up(f"fixstream-demo-{os.getpid()}", files, env, host, timeout_s=1800.0, exit_codes=codes)
    print(proc.stdout[-4000:], end="")
    new = sorted(set(recordings.glob("*.mcap")) - before)
    if proc.returncode == 0 and not new:
        print(f"demo: compose exited 0 but no recording appeared in {recordings}", file=sys.stderr)
        return 1
    if proc.returncode == 0 and codes["recorder"] != 0:  # 1: a write failed, the recording is incomplete
        print(f"demo: the player exited 0 but the recorder exited {codes['recorder']}", file=sys.stderr)
        return 1
    for path in new:
        print(f"demo: recording {path}")
    return proc.returncode


def main(argv: Sequence[str]) -> int:
    if list(argv) not in (["images"], ["demo"]):
        print("usage: python tests/container_support.py images|demo", file=sys.stderr)
        return 2
    problem = engine_problem()
    if problem:
        print(f"cannot run containers: {problem}", file=sys.stderr)
        return 2
    if argv[0] == "demo":
        return demo(REPO / "recordings")
    log: list[str] = []
    base = base_image(log)
    tag = project_image(base, log, also_tag=["localhost/fixstream:latest"])
    for line in log:
        print(line)
    print(f"base image {base}\nproject image {tag}, tagged fixstream:latest")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
