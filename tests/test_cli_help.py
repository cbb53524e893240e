"""The command line as a user meets it (issue 17, item 6): ``--help`` of every command in plain text with its
defaults, ``--version``, a validated ``--log-level``, the exit statuses, and the shell completion script."""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
from importlib import metadata

import pytest
from conftest import REPO, fixstream_cmd
from hypothesis import given
from hypothesis import strategies as st

from tools.cli.completion import bash_script
from tools.cli.help_text import plain
from tools.cli.main import COMMANDS, build_parser, main

#: what reStructuredText inline markup looks like in a help text
RST = re.compile(r"``|:[a-z]+:`|(?<![\w/*])\*\w[^*\n]*\*(?![\w*])|`[^`\s][^`]*`")


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(action.choices)


PARSER = build_parser()
SUBS = _subparsers(PARSER)


def test_every_command_is_registered_and_documented() -> None:
    assert set(SUBS) == set(COMMANDS)
    for name in ("topics", "hz", "echo", "play", "completion", "foxglove"):
        assert name in SUBS


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_help_is_plain_text_with_every_default_shown(name: str) -> None:
    sub = SUBS[name]
    text = sub.format_help()
    assert not RST.search(text), (name, RST.search(text))
    for action in sub._actions:
        default = action.default
        if (
            not action.help
            or default in (None, False, [], argparse.SUPPRESS)
            or isinstance(action, argparse._HelpAction)
            or (not action.option_strings and action.nargs is None)
        ):
            continue
        formatter = sub._get_formatter()
        shown = formatter._expand_help(action) if hasattr(formatter, "_expand_help") else action.help
        assert "default" in shown.lower(), (name, action.option_strings or action.dest, shown)
        if "%(default)" not in action.help and "default" not in action.help.lower():
            assert f"(default: {default})" in shown, (name, action.dest, shown)


def test_top_level_help_lists_the_exit_statuses() -> None:
    text = PARSER.format_help()
    for code in ("0 ok", "1 failure", "2 usage", "3 timeout"):
        assert code in text


def test_version_names_the_installed_package(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"fixstream {metadata.version('fixstream')} ")
    assert f"eclipse-zenoh {metadata.version('eclipse-zenoh')}" in out


@pytest.mark.parametrize("argv", [["--log-level", "LOUD", "scenarios"], ["scenarios", "--log-level", "verbose"]])
def test_an_unknown_log_level_is_a_usage_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(argv)
    assert done.value.code == 2
    assert "invalid log level" in capsys.readouterr().err


def test_log_level_in_either_place_and_any_case(tmp_path: object) -> None:
    args = build_parser("scenarios").parse_args(["--log-level", "debug", "scenarios"])
    assert args.log_level == "DEBUG"
    args = build_parser("scenarios").parse_args(["scenarios", "--log-level", "warning"])
    assert args.log_level == "WARNING"


def test_a_bad_log_level_in_the_environment_is_a_usage_error(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("FIXSTREAM_LOG_LEVEL", "chatty")
    with pytest.raises(SystemExit) as done:
        main(["scenarios"])
    assert done.value.code == 2 and "FIXSTREAM_LOG_LEVEL" in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv",
    [
        ["echo", "a/**/**/b"],
        ["hz"],
        ["echo", "--field", "a..b"],
        ["echo", "--field", "position_m[x]"],
        ["echo", "--once", "--count", "2"],
        ["play", "x.yaml", "--rate", "fast"],
        ["play", "x.mcap", "--all", "--keys", "fixstream/**"],
        ["play", "x.mcap", "--exclude", "a/**/**/b"],
        ["foxglove", "--key", "a/**/**/b"],
        ["hz", "k", "--clock", "wall"],
    ],
)
def test_usage_errors_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(argv)
    assert done.value.code == 2
    assert "usage: fixstream" in capsys.readouterr().err


def test_field_paths() -> None:
    from tools.cli.echo import field_path

    assert field_path("header.stamp_ns") == ("header", "stamp_ns")
    assert field_path("position_m[2]") == field_path("position_m.2") == ("position_m", 2)
    assert field_path("plots[0].range_m") == ("plots", 0, "range_m")


# ----- reStructuredText to plain text ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("rst", "text"),
    [
        ("``fixstream/**`` (default)", "fixstream/** (default)"),
        ("see :func:`~shared.codec.decode` and :mod:`shared.keys`", "see decode and shared.keys"),
        ("*Open connection* → **the** URL", "Open connection → the URL"),
        ("keys ``a/*/b`` and ``c/**``, *x*", "keys a/*/b and c/**, x"),
        (":class:`the base <shared.service.Service>`", "the base"),
    ],
)
def test_plain_strips_inline_markup(rst: str, text: str) -> None:
    assert plain(rst) == text


@given(st.text(alphabet=st.characters(blacklist_characters="`*:"), max_size=200))
def test_plain_leaves_text_without_markup_alone(text: str) -> None:
    assert plain(text) == text


@given(st.lists(st.text(alphabet=st.characters(blacklist_characters="`", blacklist_categories=["Cs"]), min_size=1)))
def test_plain_drops_every_literal_backtick_pair_and_keeps_the_content(parts: list[str]) -> None:
    rst = " ".join(f"``{p}``" for p in parts)
    assert plain(rst) == " ".join(parts)


# ----- shell completion ------------------------------------------------------------------------------------------
def _complete(script: str, *queries: tuple[str, ...]) -> list[list[str]]:
    """What bash offers for the last word of each ``fixstream <words>`` with the generated script loaded (one bash
    run for all the queries)."""
    program = [script]
    for words in queries:
        quoted = " ".join(f"'{w}'" for w in ("fixstream", *words))
        program += [
            f"COMP_WORDS=({quoted}); COMP_CWORD=$(( ${{#COMP_WORDS[@]}} - 1 )); COMPREPLY=()",
            '_fixstream; printf "%s\\n" "${COMPREPLY[@]}"; echo "--end--"',
        ]
    done = subprocess.run(
        ["bash", "--norc", "--noprofile"], input="\n".join(program), capture_output=True, text=True, cwd=REPO
    )
    assert done.returncode == 0, done.stderr
    answers = done.stdout.split("--end--\n")[: len(queries)]
    return [[w for w in a.splitlines() if w] for a in answers]


@pytest.mark.skipif(shutil.which("bash") is None, reason="no bash")
def test_bash_completion_offers_commands_options_and_choices() -> None:
    done = subprocess.run(
        fixstream_cmd("completion", "bash"), cwd=REPO, capture_output=True, text=True, timeout=60, check=True
    )
    script = done.stdout
    assert script == bash_script(build_parser())
    cases: list[tuple[tuple[str, ...], list[str] | set[str]]] = [
        (("",), list(COMMANDS)),
        (("to",), ["topics"]),
        (("--log-level", "W"), ["WARNING"]),
        (("--log-level", "INFO", "h"), ["hz"]),  # an option's value is not the command
        (("play", "x.mcap", "--ra"), ["--rate"]),
        (("hz", "k", "--clock", ""), ["receive", "stamp"]),
        (("scenarios", "v"), ["validate"]),
        (("record", "--compression", "l"), ["lz4"]),
        (("echo", "--count", ""), []),  # a number: nothing to offer
        (("hz", "fixstream/"), []),  # a key expression is not a file
        (("play", "scenarios/dem"), ["scenarios/demo.yaml"]),  # a file is
    ]
    answers = _complete(script, *(words for words, _ in cases), ("play", "--"))
    for (words, expected), got in zip(cases, answers[:-1], strict=True):
        assert got == expected, (words, got)
    assert set(answers[-1]) >= {"--keys", "--exclude", "--all", "--wait-timeout", "--progress"}


def test_zsh_completion_is_the_bash_script_behind_bashcompinit(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["completion", "zsh"]) == 0
    out = capsys.readouterr().out
    assert out == "autoload -U +X bashcompinit && bashcompinit\n" + bash_script(build_parser())
