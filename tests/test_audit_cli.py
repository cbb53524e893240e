"""The command-line findings of the new-user audit: bad arguments give one line and exit status 2 (never a
traceback), progress bars only on a terminal, ``pki`` keeps an existing CA, ``echo --field`` and ``status`` say what
went wrong, unknown service variables are warned about, and diagnostics about rejected payloads carry a stamp."""

from __future__ import annotations

import argparse
import logging
import math
import subprocess
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any, ClassVar

import msgpack
import pytest
from conftest import REPO, fixstream_cmd
from hypothesis import given
from hypothesis import strategies as st

from schemas import Depth, Diagnostic, Header, Message
from shared import codec, settings
from shared.service import Output, Service, Subscription
from shared.settings import ServiceSettings
from tools.cli import exit_codes, status
from tools.cli.common import connect_timeout, port_number
from tools.cli.main import main


def _one_line_usage(capsys: pytest.CaptureFixture[str], code: int) -> str:
    """The command's stderr, checked to be one line (no traceback) for exit status 2."""
    err = capsys.readouterr().err.strip()
    assert code == exit_codes.USAGE, err
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


def _exit_code(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exc:  # argparse's usage errors
        return int(exc.code or 0)


# ----- #6: one line and exit status 2 -----------------------------------------------------------------------------


def test_the_audits_commands_end_in_one_line_and_exit_status_2(tmp_path: Path) -> None:
    """The exact commands of the audit, as a user runs them (each was a traceback with exit status 1)."""
    a_file = tmp_path / "README.md"
    a_file.write_text("# fixstream\n\n```bash\nmake demo\n```\n: - [\n")
    runs = [
        (["foxglove", "--port", "70000"], {}, "70000"),
        (["record", "--out-dir", str(a_file)], {}, "not a directory"),
        (["run", "recorder"], {"FIXSTREAM_CONFIG_FILE": str(a_file)}, "FIXSTREAM_CONFIG_FILE"),
    ]
    for args, env, says in runs:
        done = subprocess.run(
            fixstream_cmd(*args),
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=60,
            env={**_clean_env(), **env, "FIXSTREAM_RECORDER_OUT_DIR": str(tmp_path / "rec")},
        )
        err = done.stderr.strip()
        assert done.returncode == exit_codes.USAGE, (args, err)
        assert "Traceback" not in err and says in err, (args, err)
        assert len(err.splitlines()) == 1 if args[0] != "foxglove" else err.splitlines()[-1].startswith("fixstream")


def _clean_env() -> dict[str, str]:
    import os

    return {k: v for k, v in os.environ.items() if not k.startswith("FIXSTREAM_") or k == "FIXSTREAM_STATE_DIR"}


@given(st.integers(min_value=-(10**6), max_value=10**6))
def test_a_port_is_taken_exactly_when_it_is_within_0_to_65535(port: int) -> None:
    if 0 <= port <= 65535:
        assert port_number(str(port)) == port
    else:
        with pytest.raises(argparse.ArgumentTypeError):
            port_number(str(port))


@pytest.mark.parametrize("text", ["-5", "-1.5", "nan", "soon"])
def test_a_connect_timeout_below_minus_1_is_a_usage_error(text: str) -> None:
    """It went unchecked into the settings (model_copy does not validate): -5 retried forever."""
    with pytest.raises(argparse.ArgumentTypeError):
        connect_timeout(text)
    assert [connect_timeout(t) for t in ("-1", "0", "2.5")] == [-1.0, 0.0, 2.5]


def test_record_refuses_an_out_dir_it_cannot_create(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("x")
    err = _one_line_usage(capsys, _exit_code(["record", "--out-dir", str(a_file)]))
    assert str(a_file) in err and "not a directory" in err
    err = _one_line_usage(capsys, _exit_code(["record", "--out-dir", str(a_file / "sub")]))
    assert str(a_file / "sub") in err and "cannot create" in err


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("a: [1,\n b: }\n", "line 2, column 5: expected the node content"),
        ('a: "\x01"\n', "unacceptable character #x0001"),
    ],
)
def test_play_and_mc_name_a_yaml_error_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, says: str
) -> None:
    """A scenario file that is not YAML: one line with the place of the error (yaml's own message is several
    lines with an excerpt of the file), exit status 2, for play as for mc."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    for argv in (["play", str(bad), "--rate", "0"], ["mc", str(bad), "--runs", "1", "--out", str(tmp_path / "m.json")]):
        err = _one_line_usage(capsys, _exit_code(argv))
        assert says in err and str(bad) in err, err


def test_mc_checks_out_before_the_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from tools import montecarlo

    def no_runs(*_: Any, **__: Any) -> None:
        raise AssertionError("the runs started although --out cannot be written")

    monkeypatch.setattr(montecarlo, "run_montecarlo", no_runs)
    err = _one_line_usage(capsys, _exit_code(["mc", "lbl_nav_demo", "--runs", "4", "--out", str(tmp_path)]))
    assert "is a directory" in err
    (tmp_path / "file").write_text("x")
    err = _one_line_usage(
        capsys, _exit_code(["mc", "lbl_nav_demo", "--runs", "4", "--out", str(tmp_path / "file/m.json")])
    )
    assert "not a directory" in err
    # a path that can be written: the check leaves nothing behind (the runs, here refused, would write it)
    with pytest.raises(AssertionError, match="the runs started"):
        main(["mc", "lbl_nav_demo", "--runs", "1", "--out", str(tmp_path / "new" / "m.json")])
    assert list((tmp_path / "new").iterdir()) == []


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("key: [unclosed\n", "not valid YAML"),
        ("- a\n- b\n", "expected a mapping of settings at the top level, got list"),
        ("just words\n", "got str"),
    ],
)
def test_a_config_file_that_is_not_a_mapping_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], text: str, says: str
) -> None:
    config = tmp_path / "config.yaml"
    config.write_text(text)
    monkeypatch.setenv("FIXSTREAM_CONFIG_FILE", str(config))
    monkeypatch.setenv("FIXSTREAM_RECORDER_OUT_DIR", str(tmp_path / "rec"))
    err = _one_line_usage(capsys, _exit_code(["record"]))
    assert f"FIXSTREAM_CONFIG_FILE={config}" in err and says in err


def test_an_empty_or_missing_config_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    config = tmp_path / "empty.yaml"
    config.write_text("")
    monkeypatch.setenv("FIXSTREAM_CONFIG_FILE", str(config))
    assert ServiceSettings.load().instance == "default"  # an empty file sets nothing
    monkeypatch.setenv("FIXSTREAM_CONFIG_FILE", str(tmp_path / "absent.yaml"))
    with pytest.raises(settings.StartupError, match="cannot read"):
        ServiceSettings.load()


# ----- #12: progress bars only on a terminal ----------------------------------------------------------------------


@pytest.mark.parametrize(("flags", "shown"), [([], False), (["--progress"], True), (["--no-progress"], False)])
def test_mc_and_report_draw_progress_only_on_a_terminal_unless_asked(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, flags: list[str], shown: bool
) -> None:
    """stderr here is not a terminal (pytest captures it): no bars unless --progress."""
    import tools.report
    from tools import montecarlo

    seen: list[bool] = []

    def record(*_: Any, progress: bool, **__: Any) -> Any:
        seen.append(progress)
        raise KeyboardInterrupt  # stop there: only the argument matters

    monkeypatch.setattr(montecarlo, "run_montecarlo", record)
    monkeypatch.setattr(tools.report, "make_report", record)
    assert main(["mc", "lbl_nav_demo", "--runs", "1", "--out", str(tmp_path / "m.json"), *flags]) == 130
    assert main(["report", str(tmp_path / "x.mcap"), *flags]) == 130
    assert seen == [shown, shown]


# ----- #14: pki keeps an existing CA --------------------------------------------------------------------------------


def test_pki_refuses_a_directory_with_a_ca_unless_forced(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pki = tmp_path / "pki"
    assert main(["pki", str(pki)]) == exit_codes.OK
    before = {p.name: p.read_bytes() for p in pki.iterdir()}
    capsys.readouterr()
    err = _one_line_usage(capsys, main(["pki", str(pki)]))
    assert "already holds a CA" in err and "--force" in err
    assert {p.name: p.read_bytes() for p in pki.iterdir()} == before  # nothing rewritten
    assert main(["pki", str(pki), "--force"]) == exit_codes.OK
    after = {p.name: p.read_bytes() for p in pki.iterdir()}
    assert after.keys() == before.keys() and all(after[n] != before[n] for n in before)


# ----- #13: echo --field, status selector, unknown variables -------------------------------------------------------


class _Listener:
    """Stands in for tools.cli.listen.Listener: yields the given samples, then ends as a --timeout does."""

    samples_given: ClassVar[list[SimpleNamespace]] = []

    def __init__(self, *_: Any) -> None:
        self.stopped = SimpleNamespace(is_set=lambda: False)

    def __enter__(self) -> _Listener:
        return self

    def __exit__(self, *_: Any) -> None:
        return None

    def samples(self, _timeout: float) -> Iterator[SimpleNamespace]:
        yield from self.samples_given


def test_echo_says_when_no_message_had_the_field(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import tools.cli.listen

    depth = Depth(header=Header(stamp_ns=7), depth_m=3.0)
    sample = SimpleNamespace(
        key="fixstream/sensor/a/depth/d", payload=codec.encode(depth), encoding=codec.encoding_of(Depth)
    )
    monkeypatch.setattr(_Listener, "samples_given", [sample, sample])
    monkeypatch.setattr(tools.cli.listen, "Listener", _Listener)
    assert main(["echo", "--field", "nosuch.field", "--count", "1", "--timeout", "3"]) == exit_codes.TIMEOUT
    err = capsys.readouterr().err
    hint = next(line for line in err.splitlines() if "no such field" in line)
    assert "--field nosuch.field (2 messages)" in hint
    assert "Depth: " + ", ".join(Depth.model_fields) in hint
    # a field that exists: printed, no hint
    assert main(["echo", "--field", "depth_m", "--count", "2", "--timeout", "3"]) == exit_codes.OK
    out = capsys.readouterr()
    assert out.out.splitlines() == ["fixstream/sensor/a/depth/d 3.0"] * 2 and "no such field" not in out.err


@pytest.mark.parametrize(
    ("text", "expr"),
    [
        ("lbl_nav/lbl1", "fixstream/status/lbl_nav/lbl1"),
        ("lbl_nav", "fixstream/status/lbl_nav/*"),
        ("fixstream/status/*/default", "fixstream/status/*/default"),
        ("fixstream/status/**", "fixstream/status/**"),
    ],
)
def test_status_takes_service_and_instance(text: str, expr: str) -> None:
    assert status.selector(text) == expr


@pytest.mark.parametrize("text", ["a/b/c", "lbl_nav/", "/lbl1", "lbl_nav/**/x"])
def test_status_says_which_selector_form_it_needs(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match="SERVICE/INSTANCE"):
        status.selector(text)


def test_status_help_describes_the_selector(capsys: pytest.CaptureFixture[str]) -> None:
    assert _exit_code(["status", "--help"]) == 0
    assert "SERVICE/INSTANCE (e.g. lbl_nav/lbl1)" in " ".join(capsys.readouterr().out.split())


def test_an_unknown_service_variable_is_warned_about_once(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    from services.lbl_nav.service import LblNavSettings

    monkeypatch.setattr(settings, "_warned_env", set())
    for name in ("FIXSTREAM_LBL_NAV_SIGMA_VV", "FIXSTREAM_ZENOH_NOPE", "FIXSTREAM_LOG_NOPE", "FIXSTREAM_RD_NAV_NOPE"):
        monkeypatch.setenv(name, "1")
    monkeypatch.setenv("FIXSTREAM_LBL_NAV_SIGMA_V_M", "2.5")  # a known one: no warning
    with caplog.at_level(logging.WARNING, logger="shared.settings"):
        loaded = LblNavSettings.load()
        assert isinstance(loaded, LblNavSettings) and loaded.sigma_v_m == 2.5
        LblNavSettings.load()
    warnings = [r.getMessage() for r in caplog.records]
    assert warnings == [
        "FIXSTREAM_LBL_NAV_SIGMA_VV is not a setting of LblNavSettings and is ignored;"
        " did you mean FIXSTREAM_LBL_NAV_SIGMA_V_M?"
    ]


# ----- #15: the stamp of a diagnostic about a rejected payload -----------------------------------------------------

IN_KEY = "fixstream/sensor/auv1/depth/d0"


class _Depths(Service):
    name = "stamp_test"

    def subscriptions(self) -> list[Subscription]:
        return [Subscription("fixstream/sensor/*/depth/*", self.on_depth, accepts=(Depth,), monotonic=True)]

    def on_depth(self, key: str, msg: Message) -> list[Output]:
        return []


def test_a_diagnostic_about_a_rejected_payload_carries_its_stamp_else_the_data_clock() -> None:
    svc = _Depths(ServiceSettings(instance="t", max_payload_bytes=1 << 10))
    svc._subs = svc.subscriptions()
    enc = codec.encoding_of(Depth)
    valid = Depth(header=Header(stamp_ns=5_000_000_000, source="player/x"), depth_m=3.0)
    nan = msgpack.packb({"header": {"stamp_ns": 17_400_000_000, "source": "player/x", "seq": 1}, "depth_m": math.nan})
    older = Depth(header=Header(stamp_ns=1_000_000_000, source="player/x", seq=2), depth_m=3.0)
    for payload in (
        codec.encode(valid),  # accepted: the data clock is 5 s
        nan,  # non_finite: its own stamp, 17.4 s
        b"\xc1",  # does not unpack: the data clock
        codec.encode(older),  # stamp_backwards: its own stamp, 1 s
        b"\x00" * 2000,  # payload_too_large, never unpacked: the data clock
    ):
        svc.process(IN_KEY, payload, enc, rx_time_ns=0)
    diags = [out.msg for out in svc.outbox if isinstance(out.msg, Diagnostic)]
    assert [(d.reason, d.header.stamp_ns) for d in diags] == [
        ("non_finite", 17_400_000_000),
        ("bad_msgpack", 5_000_000_000),
        ("stamp_backwards", 1_000_000_000),
        ("payload_too_large", 5_000_000_000),
    ]
