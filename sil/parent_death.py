"""Child processes of a run die with it: Linux sends them SIGTERM when the parent ends
(``PR_SET_PDEATHSIG``), however it ends, so a killed run leaves no process behind."""

from __future__ import annotations

import ctypes
import signal
import sys

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent() -> None:
    """Ask for SIGTERM when the parent process ends (Linux; elsewhere nothing)."""
    if sys.platform == "linux":
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
