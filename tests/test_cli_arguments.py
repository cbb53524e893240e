"""Out-of-range command-line values are usage errors in one line (exit code 2), never a traceback later.

Found by a new user's audit: ``--seed -1`` and ``--run -1`` ended in numpy's traceback, ``--instance a/b`` and
``--wait-for x/y/z`` in a ValueError from the key builder, ``status --timeout -1`` in "negative timeout", and NaN
was taken for a number: ``play --rate nan`` played as fast as possible, ``topics --duration nan`` never ended.
"""

from __future__ import annotations

import pytest

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
    assert err[-1].startswith(f"fixstream {argv[0]}: error: argument {option}:"), err
    assert not any("Traceback" in line for line in err)
