"""Helpers every test folder may use, as fixtures: the `sil` command in a process of its own
(``sil``, ``sil_process``), a loopback bus of a test's own (``udp_spec``, ``udp_group``), the first
difference of two logs."""

from __future__ import annotations

import os
import random
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

SIL = (sys.executable, "-m", "sil.cli")  # the `sil` command of this interpreter


def _sil(
    *args: str,
    timeout: float | None = 300,
    env: dict[str, str] | None = None,
    cwd: str | Path | None = None,
    input: str | None = None,
) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*SIL, *args], capture_output=True, text=True, timeout=timeout, env=env, cwd=cwd,
        input=input,
    )  # fmt: skip


def _sil_process(
    *args: str,
    stdout: int | None = subprocess.PIPE,
    stderr: int | None = subprocess.PIPE,
    env: dict[str, str] | None = None,
    cwd: str | Path | None = None,
) -> subprocess.Popen:
    return subprocess.Popen(
        [*SIL, *args], stdout=stdout, stderr=stderr, text=True, env=env, cwd=cwd
    )


def _udp_group() -> tuple[str, int]:
    rng = random.Random(os.getpid() ^ time.time_ns())
    return f"239.255.{rng.randrange(1, 255)}.{rng.randrange(1, 255)}", rng.randrange(20000, 60000)


def _udp_spec() -> str:
    group, port = _udp_group()
    return f"udp:{group}@{port}"


@pytest.fixture(scope="session")
def sil() -> Callable[..., subprocess.CompletedProcess]:
    """``sil(*args, timeout=300, env=None, cwd=None, input=None)``: the `sil` command in a
    process of its own, run to its end, its output kept as text (``timeout=None``: no limit)."""
    return _sil


@pytest.fixture(scope="session")
def sil_process() -> Callable[..., subprocess.Popen]:
    """``sil_process(*args, stdout=PIPE, stderr=PIPE, env=None, cwd=None)``: the `sil` command
    started in a process of its own, its output as text; the test waits for it or ends it."""
    return _sil_process


@pytest.fixture(scope="session")
def udp_spec() -> Callable[[], str]:
    """``udp_spec()``: a loopback bus spec no other test uses."""
    return _udp_spec


@pytest.fixture
def udp_group() -> tuple[str, int]:
    """A loopback multicast group and port no other test uses."""
    return _udp_group()


def _first_difference(a: bytes, b: bytes) -> str | None:
    """The first differing line of two logs, or None when they are equal (pytest's own diff of
    megabytes never ends)."""
    la, lb = a.splitlines(), b.splitlines()
    for i, (x, y) in enumerate(zip(la, lb, strict=False)):
        if x != y:
            return f"line {i + 1}: {x!r} != {y!r}"
    return None if len(la) == len(lb) else f"lengths differ: {len(la)} != {len(lb)} lines"


@pytest.fixture
def first_difference() -> Callable[[bytes, bytes], str | None]:
    return _first_difference


# The fast tier (`python3 dev.py test --quick`, the marker expression "not slow and not vcan and
# not machine_speed") leaves out what flies whole runs, starts node processes or QEMU, runs a
# bench or a long fuzz: every test of these modules is marked slow (a test elsewhere carries its
# own @pytest.mark.slow). The whole suite (`python3 dev.py test`) runs them all.
SLOW_MODULES = frozenset(
    {
        "campaign/test_bridge.py",
        "campaign/test_campaign.py",
        "ecu/test_verify.py",
        "plant/test_schedules.py",
        "port/test_node.py",
        "port/test_pil.py",
        "port/test_sil.py",
        "service/test_bench_start.py",
        "service/test_storage.py",
        "sil/test_bench.py",
        "sil/test_compiled_loop.py",
        "sil/test_control_bench.py",
        "sil/test_fleet_bench.py",
        "sil/test_foreign_frames.py",
        "sil/test_identify.py",
        "sil/test_identify_sil.py",
        "sil/test_lockstep_load.py",
        "sil/test_log_damage.py",
        "sil/test_mode_equivalence.py",
        "sil/test_realtime_bench.py",
        "sil/test_recorder_process.py",
        "sil/test_recorder_ticks.py",
        "sil/test_replay.py",
        "sil/test_results.py",
        "sil/test_run.py",
        "sil/test_run_record.py",
        "sil/test_shared_bus.py",
        "sil/test_start_runs.py",
        "sil/test_thesis_claims.py",
        "sil/test_transient_metrics.py",
        "sil/test_verify_document.py",
        "sil/test_watchdog.py",
        "test_cli.py",
        "test_cli_robustness.py",
        "xcp/test_lockstep.py",
        "xcp/test_pyxcp.py",
        "xcp/test_calibration_doc.py",
        "xcp/test_daq_mf4.py",
        "xcp/test_c_node.py",
        "sil/test_mdf.py",
    }
)
TESTS = Path(__file__).resolve().parent


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.relative_to(TESTS).as_posix() in SLOW_MODULES:
            item.add_marker(pytest.mark.slow)
