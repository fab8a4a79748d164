"""Fixtures of the SIL tests: the `sil` command in a process of its own, a loopback bus of a
test's own."""

from __future__ import annotations

import os
import random
import subprocess
import sys
import time
from collections.abc import Callable

import pytest


def _sil(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sil.cli", *args], capture_output=True, text=True, timeout=timeout
    )


def _udp_spec() -> str:
    rng = random.Random(os.getpid() ^ time.time_ns())
    group = f"239.255.{rng.randrange(1, 255)}.{rng.randrange(1, 255)}"
    return f"udp:{group}@{rng.randrange(20000, 60000)}"


@pytest.fixture(scope="session")
def sil() -> Callable[..., subprocess.CompletedProcess]:
    """``sil(*args, timeout=...)``: the `sil` command in a process of its own, its output kept."""
    return _sil


@pytest.fixture(scope="session")
def udp_spec() -> Callable[[], str]:
    """``udp_spec()``: a loopback bus spec no other test uses."""
    return _udp_spec
