#!/usr/bin/env python3
"""Set up the project's own environment and run its main jobs.

    python3 dev.py demo     create .venv, install, run the SIL demo on the default bus (MRAC and
                            PID on the staircase; results and plots in out/demo)
    python3 dev.py test     create .venv, install, lint and run the whole test suite
    python3 dev.py test --quick
                            the fast tier for the inner loop: no slow, virtual-machine or
                            machine-speed tests (a few minutes on 2 cores)

Both are idempotent: the install step runs again only when pyproject.toml changes.
Extra arguments after `test` go to pytest (for example `python3 dev.py test -k replay`).
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
SLOWEST = 15  # the slowest tests listed after a run


def _run(*cmd: str | Path) -> int:
    return subprocess.call([str(c) for c in cmd], cwd=ROOT)


def setup() -> None:
    """Create .venv and install the package with its test extras, unless already current."""
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
    if "--quick" in rest:
        rest = [a for a in rest if a != "--quick"]
        rest = ["-m", QUICK, *rest]
    # pytest exits 5 when it collected no test: that is a failure here, as any non-zero exit.
    # The slowest tests are listed at the end, where a slower suite shows first.
    return _run(BIN / "python", "-m", "pytest", f"--durations={SLOWEST}", *rest)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
