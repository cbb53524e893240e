"""Compose variable interpolation, against the rules of the Compose Specification (interpolation chapter)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tools.stack.interpolate import InterpolationError, interpolate, interpolate_tree, parse_env_file

ENV = {"SET": "value", "EMPTY": "", "OTHER": "other"}


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("$SET", "value"),
        ("${SET}", "value"),
        ("pre-${SET}-post", "pre-value-post"),
        ("$SET/x", "value/x"),
        ("$SET_more", ""),  # the name is greedy: SET_more is unset
        ("${UNSET}", ""),
        ("$UNSET", ""),
        # :- default when unset or empty; - only when unset
        ("${UNSET:-d}", "d"),
        ("${EMPTY:-d}", "d"),
        ("${SET:-d}", "value"),
        ("${UNSET-d}", "d"),
        ("${EMPTY-d}", ""),
        ("${SET-d}", "value"),
        ("${UNSET:-}", ""),
        # :+ / + alternative value
        ("${SET:+alt}", "alt"),
        ("${EMPTY:+alt}", ""),
        ("${UNSET:+alt}", ""),
        ("${EMPTY+alt}", "alt"),
        ("${UNSET+alt}", ""),
        # required values that are present
        ("${SET:?must be set}", "value"),
        ("${SET?must be set}", "value"),
        ("${EMPTY?must be set}", ""),
        # nesting
        ("${UNSET:-${SET}}", "value"),
        ("${UNSET:-${ALSO_UNSET:-deep}}", "deep"),
        ("${UNSET:-a-$OTHER-b}", "a-other-b"),
        ("${SET:-${UNSET:?not evaluated when unused}}", "value"),
        # defaults may hold characters that are special elsewhere
        ("${UNSET:-scenarios/demo.yaml}", "scenarios/demo.yaml"),
        ("${UNSET:-a:b-c}", "a:b-c"),
        ("${UNSET:-./recordings}:/data/recordings", "./recordings:/data/recordings"),
        # $$ escapes, a lone $ is kept
        ("$$SET", "$SET"),
        ("$${SET}", "${SET}"),
        ("cost: $$5", "cost: $5"),
        ("$$$SET", "$value"),
        ("price $5", "price $5"),
        ("trailing $", "trailing $"),
        ("no variables", "no variables"),
    ],
)
def test_interpolate_rules(text: str, expected: str) -> None:
    assert interpolate(text, ENV) == expected


def test_unset_variable_warns() -> None:
    warnings: list[str] = []
    assert interpolate("x${UNSET}y$ALSO", ENV, warnings.append) == "xy"
    assert len(warnings) == 2
    assert "UNSET" in warnings[0] and "ALSO" in warnings[1]
    warnings.clear()
    interpolate("${UNSET:-d} ${UNSET-d} ${SET}", ENV, warnings.append)
    assert warnings == []


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("${UNSET:?set UNSET please}", "set UNSET please"),
        ("${EMPTY:?must not be empty}", "must not be empty"),
        ("${UNSET?needed}", "needed"),
        ("${UNSET:?}", "UNSET"),
        ("${UNSET:?missing $OTHER}", "missing other"),
    ],
)
def test_missing_required_is_an_error(text: str, fragment: str) -> None:
    with pytest.raises(InterpolationError, match="required variable") as info:
        interpolate(text, ENV)
    assert fragment in str(info.value)


@pytest.mark.parametrize("text", ["${", "${SET", "${}", "${1BAD}", "${SET/x/y}", "${SET:-unclosed"])
def test_malformed_is_an_error(text: str) -> None:
    with pytest.raises(InterpolationError, match="invalid interpolation format"):
        interpolate(text, ENV)


def test_tree_interpolates_values_not_keys() -> None:
    tree = {"services": {"$SET": {"command": ["a", "${SET}", 3, True], "environment": {"K": "${OTHER}"}}}}
    out = interpolate_tree(tree, ENV)
    assert out == {"services": {"$SET": {"command": ["a", "value", 3, True], "environment": {"K": "other"}}}}


def test_tree_error_names_the_path() -> None:
    with pytest.raises(InterpolationError, match=r"services\.player\.command\[1\]"):
        interpolate_tree({"services": {"player": {"command": ["x", "${NEED:?give NEED}"]}}}, ENV)


def test_env_file(tmp_path: Path) -> None:
    path = tmp_path / ".env"
    path.write_text(
        "\n".join(
            [
                "# a comment",
                "",
                "PLAIN=plain value",
                "export EXPORTED=yes",
                "SINGLE='literal $SET ${X}'",
                'DOUBLE="double ${SET} \\"q\\""',
                "COMMENTED=abc # trailing comment",
                "HASH=a#b",
                "REF=${PLAIN}-x",
                "DEFAULTED=${NOPE:-fallback}",
                "EMPTY=",
            ]
        )
    )
    values = parse_env_file(path, ENV)
    assert values == {
        "PLAIN": "plain value",
        "EXPORTED": "yes",
        "SINGLE": "literal $SET ${X}",
        "DOUBLE": 'double value "q"',
        "COMMENTED": "abc",
        "HASH": "a#b",
        "REF": "plain value-x",
        "DEFAULTED": "fallback",
        "EMPTY": "",
    }


def test_env_file_rejects_garbage(tmp_path: Path) -> None:
    path = tmp_path / ".env"
    path.write_text("OK=1\nthis is not an assignment\n")
    with pytest.raises(InterpolationError, match=":2:"):
        parse_env_file(path)
