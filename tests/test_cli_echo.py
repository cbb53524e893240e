"""``fixstream echo`` with ``--once``, ``--count``, ``--field`` and ``--timeout`` over a real router (issue 17,
item 6), and the field paths it reads."""

from __future__ import annotations

import json

import pytest
from cli_support import TestPublisher, depth, finish, start, truth
from hypothesis import given, settings
from hypothesis import strategies as st

from tools.cli.echo import MissingField, extract, field_path

MS = 1_000_000

json_leaf = st.none() | st.booleans() | st.integers() | st.text(max_size=5)
json_tree = st.recursive(
    json_leaf,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.from_regex(r"[a-z_]{1,6}", fullmatch=True), inner),
    max_leaves=20,
)


def _paths(obj: object, prefix: tuple[str | int, ...] = ()) -> list[tuple[tuple[str | int, ...], object]]:
    """Every (path, value) of a JSON tree, computed independently of extract()."""
    out: list[tuple[tuple[str | int, ...], object]] = [(prefix, obj)]
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _paths(v, (*prefix, i))
    return out


@settings(max_examples=60, deadline=None)
@given(json_tree)
def test_extract_finds_every_value_at_its_path_and_nothing_elsewhere(tree: object) -> None:
    for path, value in _paths(tree):
        assert extract(tree, path) == value
        text = ".".join(str(p) for p in path)
        if path and all(isinstance(p, int) or p.isidentifier() for p in path):
            assert field_path(text) == path
    with pytest.raises(MissingField):
        extract(tree, ("no_such_field_anywhere_x",) if not isinstance(tree, dict) else ("0" * 7,))


@pytest.mark.e2e
def test_echo_once_count_field_and_timeout(router: str) -> None:
    """Each client listens on its own prefix, so that the test can wait until each one's subscriber is routed."""
    once = start("echo", "fixstream/once/**", "--once", "--field", "header.stamp_ns", "--connect", router)
    fields = start(
        "echo",
        "fixstream/fields/**",
        "--json",
        "--count",
        "2",
        "--field",
        "position_m[1]",
        "--field",
        "header.seq",
        "--timeout",
        "30",
        "--connect",
        router,
    )
    # nothing is published on this key: --count 2 is not reached within --timeout, exit status 3
    short = start("echo", "fixstream/nothing/**", "--count", "2", "--timeout", "0.5", "--connect", router)
    pub = TestPublisher(router)
    try:
        for prefix in ("fixstream/once", "fixstream/fields"):
            pub.wait_for_subscriber(f"{prefix}/p1")
            pub.put(f"{prefix}/d", depth(1, 5 * MS))  # no position_m: skipped by the field echo
            for seq in (5, 6, 7):
                pub.put(f"{prefix}/p1", truth(seq, (seq + 2) * MS))
    finally:
        pub.close()
    code, out, err = finish(once)
    assert code == 0, err
    assert out.splitlines() == ["fixstream/once/d 5000000"]  # the first message, its stamp only
    code, out, err = finish(fields)
    assert code == 0, err
    key = "fixstream/fields/p1"
    assert [json.loads(line) for line in out.splitlines()] == [
        {"key": key, "schema": "Truth", "fields": {"position_m.1": 10.0, "header.seq": 5}},
        {"key": key, "schema": "Truth", "fields": {"position_m.1": 12.0, "header.seq": 6}},
    ]
    code, out, err = finish(short)
    assert code == 3 and not out
    assert err.strip() == "fixstream echo: 0 of 2 messages on fixstream/nothing/** in 0.5 s"
