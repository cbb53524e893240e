"""A second process under a name that is already alive refuses to start (one line, exit code 2).

Found by a new user's audit: ``FIXSTREAM_LBL_NAV_INSTANCE=lbl1 fixstream run lbl_nav`` beside a stack's lbl1
started silently; the fix stream doubled under one source with two seq counters, the recorder reported ``lost:
6035``, and ``fixstream status`` listed ``lbl_nav/lbl1`` twice. Real processes on a real router.
"""

from __future__ import annotations

import json
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager

import zenoh
from conftest import REPO, fixstream_cmd, service_env, wait_until

from shared import keys
from shared.service import Service
from shared.session import open_session, query_all
from shared.settings import ZenohSettings


def _lbl_nav(env: dict[str, str]) -> subprocess.Popen[bytes]:
    return subprocess.Popen(fixstream_cmd("run", "lbl_nav"), env=env, cwd=REPO, stderr=subprocess.DEVNULL)


def _serving(client: zenoh.Session, instance: str) -> bool:
    """Whether ``lbl_nav/<instance>`` answers its status: past the namesake check and serving (a liveliness token
    can still be a crashed predecessor's for a moment)."""
    return any(r.ok for r in query_all(client, keys.status("lbl_nav", instance), 0.5))


@contextmanager
def _one_lbl_nav(router: str, instance: str) -> Iterator[tuple[zenoh.Session, subprocess.Popen[bytes], dict[str, str]]]:
    """A serving ``fixstream run lbl_nav`` of ``instance`` and a client session; yields them and the environment
    that names the instance; the process, unless the test killed it, must end cleanly when terminated."""
    env = service_env(router, FIXSTREAM_LBL_NAV_INSTANCE=instance)
    client = open_session(ZenohSettings(mode="client", connect=[router]))
    first = _lbl_nav(env)
    try:
        assert wait_until(lambda: _serving(client, instance), 30.0)
        yield client, first, env
    finally:
        client.close()
        if first.poll() is None:  # not killed by the test itself
            first.terminate()
            assert first.wait(timeout=30) == 0


def test_a_namesake_is_refused_and_the_first_process_keeps_running(router: str) -> None:
    with _one_lbl_nav(router, "lbl1") as (client, first, env):
        started = time.monotonic()
        second = subprocess.run(
            fixstream_cmd("run", "lbl_nav"), env=env, cwd=REPO, capture_output=True, text=True, timeout=60
        )
        waited = time.monotonic() - started
        assert second.returncode == 2, second.stderr
        last = second.stderr.strip().splitlines()[-1]
        assert "another process is already alive as fixstream/alive/lbl_nav/lbl1" in last, second.stderr
        assert "Traceback" not in second.stderr
        assert waited >= Service.namesake_wait_s  # it waited for the namesake to go before refusing
        replies = [r.ok for r in query_all(client, keys.status("lbl_nav", "lbl1"), 3.0) if r.ok]
        assert len(replies) == 1 and first.poll() is None  # one lbl1, still serving
        status = json.loads(replies[0].payload.to_bytes())
        assert status["subscribed"] == [status["keys"]["in"]]  # every service says what it listens to


def test_sigterm_stops_a_namesake_that_is_still_waiting(router: str) -> None:
    """Compose stops a container with SIGTERM and kills it 10 s later: the wait must not outlast that."""
    with _one_lbl_nav(router, "lbl3") as (_, _first, env):
        second = _lbl_nav(env)
        time.sleep(4.0)  # started and waiting for the namesake to go
        assert second.poll() is None
        stopped = time.monotonic()
        second.terminate()
        assert second.wait(timeout=Service.namesake_wait_s) == 0
        assert time.monotonic() - stopped < 3.0


def test_a_restart_after_a_crash_is_not_a_namesake(router: str) -> None:
    """SIGKILL closes the crashed process's link at once, so its token goes and the restarted one starts."""
    with _one_lbl_nav(router, "lbl2") as (client, crashed, env):
        crashed.kill()
        crashed.wait()
        started = time.monotonic()
        again = _lbl_nav(env)
        try:
            assert wait_until(lambda: _serving(client, "lbl2"), 30.0)
            assert again.poll() is None and time.monotonic() - started < Service.namesake_wait_s
        finally:
            again.terminate()
            assert again.wait(timeout=30) == 0


def test_a_second_player_of_one_instance_is_refused_and_the_first_plays_on(router: str) -> None:
    """An operator's churn audit: a second ``fixstream play`` of the same instance was accepted silently; both
    published as ``player/default`` with two seq counters, and terrain_nav counted 71,144 of 4,808 messages lost."""
    env = service_env(router)
    play = [*fixstream_cmd("play", "lbl_nav_demo", "--rate", "1", "--no-wait", "--connect", router)]
    first = subprocess.Popen(play, env=env, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    client = open_session(ZenohSettings(mode="client", connect=[router]))
    try:
        alive = keys.alive("player", "default")
        assert wait_until(lambda: any(r.ok for r in client.liveliness().get(alive, timeout=0.5)), 30.0)
        second = subprocess.run(play, env=env, cwd=REPO, capture_output=True, text=True, timeout=60)
        assert second.returncode == 2, second.stderr
        assert "another process is already alive as fixstream/alive/player/default" in second.stderr
        assert "Traceback" not in second.stderr and first.poll() is None  # the first plays on
        other = [*play[:-2], "--instance", "other", "--rate", "0", "--connect", router]
        assert subprocess.run(other, env=env, cwd=REPO, capture_output=True, timeout=60).returncode == 0
    finally:
        client.close()
        first.terminate()
        first.wait(timeout=30)
