"""Every option of every `sil` command, given odd values: the parser takes the value or refuses
it as a usage error (exit 2) in one line naming the option; no option's type check raises
anything else (a traceback) or writes more than that line.

The commands and options are read from the parser itself, so a new option is fuzzed the day it
is added. The number of examples per option is ``SIL_ROBUSTNESS_EXAMPLES`` / 10 (at least 5).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sil.cli import build_parser

EXAMPLES = max(5, int(os.environ.get("SIL_ROBUSTNESS_EXAMPLES", "200")) // 10)

ODD_TEXT = st.one_of(
    st.sampled_from(
        [
            "", " ", "-", "--", "nan", "NaN", "inf", "-inf", "1e-300", "1e309", "-0", "0x10",
            "9" * 40, "/proc/foo", "/sys/foo", "/nonexistent/dir/file", ".", "/", "\x00",
            "a=b", "=", "udp:", "virtual:", "kvaser:0", "1,2", "0x700,0x700", "-1", "0",
        ]
    ),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-(10**20), max_value=10**20).map(str),
    st.text(max_size=12),
)  # fmt: skip


def _options() -> list[tuple[str, str, list[str]]]:
    """(command, option, the command's required positionals filled with a placeholder) for
    every option of every command that takes a value."""
    out = []
    parser = build_parser([])
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, command in sorted(sub.choices.items()):
        actions = command._actions
        positionals = ["X" for a in actions if not a.option_strings and a.required and a.nargs != 0]
        if any(isinstance(a, argparse._SubParsersAction) and a.required for a in actions):
            continue  # a command of actions (log, xcp): its actions carry their own options
        for action in actions:
            if action.option_strings and action.nargs != 0 and action.dest != "help":
                out.append((name, action.option_strings[-1], positionals))
    return out


OPTIONS = _options()


def test_the_fuzz_covers_the_commands_options():
    commands = {c for c, _, _ in OPTIONS}
    wanted = {"run", "ecu", "plant", "replay", "campaign", "identify", "bridge", "console"}
    assert wanted <= commands
    assert len(OPTIONS) > 60


@pytest.mark.parametrize(("command", "option", "positionals"), OPTIONS)
@settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(value=ODD_TEXT)
def test_an_odd_value_is_taken_or_refused_naming_the_option(command, option, positionals, value):
    parser = build_parser([command])
    argv = [command, *positionals, f"{option}={value}"]
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            parser.parse_args(argv)
        except SystemExit as exc:
            assert exc.code == 2, f"{argv}: exit {exc.code}"
            last = err.getvalue().strip().splitlines()[-1]
            assert option in last or "argument" in last, f"{argv}: {last!r}"
            assert "Traceback" not in err.getvalue()
