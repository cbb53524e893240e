"""Out-of-range command-line values are usage errors in one line (exit code 2), never a traceback later.

Found by a new user's audit: ``--seed -1`` and ``--run -1`` ended in numpy's traceback, ``--instance a/b`` and
``--wait-for x/y/z`` in a ValueError from the key builder, ``status --timeout -1`` in "negative timeout", and NaN
was taken for a number: ``play --rate nan`` played as fast as possible, ``topics --duration nan`` never ended.
A second audit: values too large to act on (``mc --runs 1e12``: MemoryError; ``status --timeout 1e20``,
``play --linger 1e30``, ``play --rate 1e-300``, ``hz --window 1e20``: tracebacks from the OS's wait or a deque),
``up``'s and ``router``'s seconds (not checked at all: ``router --block-close-s nan`` was a traceback), a file that is
not UTF-8 text, a scenario directory whose every file is invalid, and a scheduler address Dask cannot parse (its
half-built client waited 40 s, then a traceback).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import REPO

from tools.cli.main import main

BAD = [
    ("play", "demo", "--seed", "-1"),
    ("play", "demo", "--run", "-1"),
    ("play", "demo", "--instance", "a/b"),
    ("play", "demo", "--instance", ""),
    ("play", "demo", "--wait-for", "x/y/z"),
    ("play", "demo", "--rate", "nan"),
    ("play", "demo", "--rate", "-1"),
    ("play", "demo", "--linger", "-5"),
    ("play", "demo", "--wait-timeout", "inf"),
    ("mc", "demo", "--runs", "1", "--seed", "-5"),
    ("mc", "demo", "--runs", "0"),
    ("scenarios", "show", "demo", "--seed", "-2"),
    ("record", "--instance", "a*"),
    ("status", "--timeout", "-1"),
    ("status", "--timeout", "nan"),
    ("echo", "fixstream/**", "--timeout", "-1"),
    ("topics", "--duration", "nan"),
    ("hz", "fixstream/**", "--duration", "-3"),
    ("foxglove", "--timeout", "-1"),
    ("mc", "demo", "--runs", "1000000000000"),
    ("mc", "demo", "--runs", "-1"),
    ("status", "--timeout", "1e20"),
    ("play", "demo", "--linger", "1e30"),
    ("play", "demo", "--rate", "1e-300"),
    ("play", "demo", "--seed", "99999999999999999999"),
    ("hz", "fixstream/**", "--window", "100000000000000000000"),
    ("hz", "fixstream/**", "--interval", "nan"),
    ("hz", "fixstream/**", "--interval", "0"),
    ("hz", "fixstream/**", "--count", "-1"),
    ("up", "--drain", "nan"),
    ("up", "--ready-timeout", "-5"),
    ("up", "--timeout", "inf"),
    ("router", "--block-close-s", "nan"),
]


@pytest.mark.parametrize("argv", BAD, ids=[" ".join(a) for a in BAD])
def test_an_out_of_range_value_is_a_one_line_usage_error(
    argv: tuple[str, ...], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exited:
        main(list(argv))
    assert exited.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    option = [a for a in argv if a.startswith("--")][-1]  # the bad value is the last option
    assert err[-1].startswith(f"fixstream {argv[0]}: error: argument "), err
    assert f"{option}: " in err[-1], err  # "-t/--timeout: " for an option with a short form
    assert not any("Traceback" in line for line in err)


def test_a_range_message_names_both_bounds(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["mc", "demo", "--runs", "-1"])
    assert "must be between 1 and 10,000,000" in capsys.readouterr().err  # not ">= 0", then ">= 1" for 0


NOT_TEXT = b"\x89PNG\r\n\x1a\n\x00\x00binary"


@pytest.mark.parametrize(
    "argv",
    [
        ["scenarios", "validate", "{f}"],
        ["scenarios", "show", "{f}"],
        ["play", "{f}"],
        ["mc", "{f}", "--runs", "1", "--out", "{d}/o.json"],
        ["up", "-f", "{f}", "--dry-run"],
        ["up", "--env-file", "{f}", "--dry-run"],
    ],
    ids=lambda a: " ".join(a[:2]),
)
def test_a_file_that_is_not_text_is_one_line(
    argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    f = tmp_path / "notyaml.yaml"
    f.write_bytes(NOT_TEXT)
    monkeypatch.chdir(REPO)  # up --env-file needs the compose file
    code = main([a.format(f=f, d=tmp_path) for a in argv])
    assert code in (1, 2) if argv[1] == "validate" else code == 2
    err = capsys.readouterr()
    lines = (err.err + err.out).strip().splitlines()
    assert any(f"{f}: not UTF-8 text" in line for line in lines), lines
    assert not any("Traceback" in line for line in lines)


def test_a_directory_of_invalid_files_lists_them_and_a_bad_one_spoils_no_lookup(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    demo = (REPO / "scenarios" / "lbl_nav_demo.yaml").read_text()
    (tmp_path / "a.yaml").write_bytes(NOT_TEXT)
    (tmp_path / "b.yaml").write_text(demo.replace("duration_s", "duraton_s").replace("lbl_nav_demo", "other"))
    assert main(["scenarios", "list", "--dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split()[:2] for line in out] == [["a.yaml", "INVALID"], ["b.yaml", "INVALID"]], out
    (tmp_path / "c.yaml").write_text(demo)  # found by its name past the two bad files
    assert main(["scenarios", "show", "lbl_nav_demo", "--dir", str(tmp_path)]) == 0
    assert capsys.readouterr().out.startswith(f"# {tmp_path / 'c.yaml'}")
    assert main(["scenarios", "list", "--dir", str(tmp_path / "missing")]) == 2
    assert "not a directory" in capsys.readouterr().err


def test_a_scheduler_address_dask_cannot_parse_is_refused_at_once(tmp_path: Path) -> None:
    pytest.importorskip("distributed")
    from tools.montecarlo import DaskUnavailable, check_scheduler_address

    for bad in ("garbage", "tcp://host", "tcp://:8786", "tcp://host:0"):
        with pytest.raises(DaskUnavailable, match="expected tcp://HOST:PORT"):
            check_scheduler_address(bad)
    for good in ("tcp://127.0.0.1:8786", "scheduler:8786", "tls://host:1"):
        check_scheduler_address(good)


@pytest.mark.parametrize("option", [["--seed", "3"], ["--run", "1"], ["--instance", "other"]])
def test_scenario_options_on_a_recording_are_refused_not_ignored(
    option: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    """A recording replays its messages as recorded, headers included: these options used to be silently ignored."""
    assert main(["play", "rec.mcap", *option]) == 2
    assert f"{option[0]} apply to a scenario file, not a recording" in capsys.readouterr().err
