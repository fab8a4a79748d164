#!/usr/bin/env python3
"""Set up the project's own environment and run its main jobs.

    python3 dev.py demo     create .venv, install, run the SIL demo on the default bus (MRAC and
                            PID on the staircase; results and plots in out/demo)
    python3 dev.py test     create .venv, install, lint and run the whole test suite
    python3 dev.py test --quick
                            the fast tier for the inner loop: no slow, virtual-machine or
                            machine-speed tests (a few minutes on 2 cores)

Both are idempotent: the install step runs again only when pyproject.toml changes, the build
of the compiled firmware tick only when its sources do.
Extra arguments after `test` go to pytest (for example `python3 dev.py test -k replay`).

The tests run in two parts: first those that do not depend on the wall clock, on every core
(pytest-xdist, each module on one worker), then those paced by the wall clock or asserting the
machine's pace, one at a time with the machine to themselves (marker expression APART). Each
part lists its slowest tests.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
STAMP = VENV / ".setup-stamp"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
QUICK = "not slow and not vcan and not machine_speed"  # the fast tier's marker expression
APART = "realtime or machine_speed"  # tests that run alone, after the others
SLOWEST = 15  # the slowest tests listed after each part
NO_TESTS = 5  # pytest's exit status when it collected nothing


def _run(*cmd: str | Path) -> int:
    return subprocess.call([str(c) for c in cmd], cwd=ROOT)


def setup() -> None:
    """Create .venv and install the package with its test extras, unless already current; then
    build the firmware tick's compiled modules when their sources changed (ecu.compiled_tick:
    without a C compiler the tick runs interpreted, as fast as before)."""
    _install()
    _run(BIN / "python", "-m", "ecu.build_tick", "build", "--if-stale")


def _install() -> None:
    wanted = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    if STAMP.exists() and STAMP.read_text().strip() == wanted:
        return
    if not (BIN / "python").exists():
        print("dev.py: creating .venv", flush=True)
        subprocess.check_call([sys.executable, "-m", "venv", str(VENV)])
    print("dev.py: installing turbojet-sil and its test extras into .venv", flush=True)
    subprocess.check_call([str(BIN / "python"), "-m", "pip", "install", "-q", "--upgrade", "pip"])
    subprocess.check_call(
        [str(BIN / "python"), "-m", "pip", "install", "-q", "-e", f"{ROOT}[test]"]
    )
    STAMP.write_text(wanted + "\n")


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("demo", "test", "setup"):
        print(__doc__.strip())
        return 2
    setup()
    job, rest = argv[0], argv[1:]
    if job == "setup":
        return 0
    if job == "demo":
        return _run(BIN / "sil", "demo", *rest)
    lint = _run(BIN / "ruff", "check", "--quiet", ".")
    if lint != 0:
        print("dev.py: ruff found problems (see above)", file=sys.stderr)
        return lint
    return test(rest)


def _marker_expression(args: list[str]) -> tuple[str | None, list[str]]:
    """The -m expression among pytest's arguments (``-m EXPR``, ``-mEXPR`` or ``-m=EXPR``),
    and the arguments without it."""
    expression, others, items = None, [], iter(args)
    for arg in items:
        if arg == "-m":
            expression = next(items, "")
        elif arg.startswith("-m") and not arg.startswith("--"):
            expression = arg[2:].removeprefix("=")
        else:
            others.append(arg)
    return expression, others


def test(args: list[str]) -> int:
    """The suite in its two parts (module docstring). A part that selects no test is fine when
    the other ran some; no test at all is a failure (pytest's exit 5), as any non-zero exit."""
    quick = "--quick" in args
    expression, rest = _marker_expression([a for a in args if a != "--quick"])
    chosen = " and ".join(f"({e})" for e in (QUICK if quick else None, expression) if e)
    both = f"({chosen}) and " if chosen else ""
    workers = str(max(1, min(os.cpu_count() or 1, 4)))
    pytest = [BIN / "python", "-m", "pytest", f"--durations={SLOWEST}"]
    print(f"dev.py: tests that do not depend on the wall clock, on {workers} workers", flush=True)
    every_core = ["-n", workers, "--dist", "loadfile", "--no-loadscope-reorder"]
    shared = _run(*pytest, *every_core, "-m", f"{both}not ({APART})", *rest)
    print("dev.py: tests paced by the wall clock, one at a time", flush=True)
    alone = _run(*pytest, "-m", f"{both}({APART})", *rest)
    if shared == alone == NO_TESTS:
        return NO_TESTS
    codes = [code for code in (shared, alone) if code not in (0, NO_TESTS)]
    return codes[0] if codes else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
