"""Fixtures of the SIL tests: the `sil` command in a process of its own, a loopback bus of a
test's own, a short scenario file."""

from __future__ import annotations

import os
import random
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

SHORT_SCENARIO = """
description = "short MRAC staircase for tests"
duration_s = {duration}
[plant]
model = "aero"
[controller]
kind = "mrac"
preset = "sec5_3_mrac_aero"
params = {{ limiters_on = 1, dead_zone_on = 1, speed_noise_rpm = 20, rate_window_s = 0.05 }}
[command]
base = 0
[[command.component]]
kind = "staircase"
levels = [90, 92, 88]
step_s = 1
[[fault]]
time_s = 1.5
target = "PUMP_EFFECTIVENESS"
value = 0.8
"""


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


@pytest.fixture
def short_scenario(tmp_path: Path) -> Callable[..., Path]:
    """``short_scenario(duration=3.0)``: a file of a short MRAC staircase with a pump fault."""

    def write(duration: float = 3.0) -> Path:
        path = tmp_path / f"short-{duration:g}.toml"
        path.write_text(SHORT_SCENARIO.format(duration=duration))
        return path

    return write
