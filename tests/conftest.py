"""Helpers every test folder may use, as fixtures: the `sil` command in a process of its own
(``sil``, ``sil_process``), a loopback bus of a test's own (``udp_spec``, ``udp_group``), the first
difference of two logs."""

from __future__ import annotations

import json
import os
import random
import select
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


class BenchConsole:
    """``sil console PORT ... --json`` in a process of its own, as an operator at a bench types
    it: ``console(port, *args)`` its answer as JSON, ``console.live(port, count)`` that many
    live samples, ``console.until(port, done, limit_s)`` live samples until ``done(sample)``
    or ``limit_s`` (the last sample)."""

    def __call__(self, port: str, *args: str) -> dict | list:
        done = _sil("console", port, *args, "--json", timeout=30)
        assert done.returncode == 0, done.stderr
        return json.loads(done.stdout)

    def live(self, port: str, count: int) -> list[dict]:
        return self(port, "live", "--samples", str(count))  # type: ignore[return-value]

    def until(self, port: str, done: Callable[[dict], bool], limit_s: float) -> dict:
        deadline = time.monotonic() + limit_s
        while True:
            sample = self.live(port, 1)[0]
            if done(sample) or time.monotonic() > deadline:
                return sample
            time.sleep(0.3)


@pytest.fixture(scope="session")
def console() -> BenchConsole:
    return BenchConsole()


def _stderr_line(proc: subprocess.Popen, prefix: str, limit_s: float = 60) -> str:
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        if select.select([proc.stderr], [], [], 1.0)[0]:
            line = proc.stderr.readline()
            assert line, f"the process exited with {proc.poll()} before printing {prefix!r}"
            if line.startswith(prefix):
                return line[len(prefix) :].strip()
    raise AssertionError(f"no {prefix!r} line within {limit_s} s")


@pytest.fixture(scope="session")
def stderr_line() -> Callable[..., str]:
    """``stderr_line(proc, prefix, limit_s=60)``: the rest of the first line of a process's
    stderr that starts with ``prefix`` (a node's service port, its XCP IDs ...)."""
    return _stderr_line


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
# own @pytest.mark.slow, or is named in SLOW_TESTS below), and every test that asserts the
# machine's pace is marked machine_speed (MACHINE_SPEED_TESTS). The whole suite
# (`python3 dev.py test`) runs them all.
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
# Single tests of the modules the fast tier keeps, marked slow here ("module::test" for every
# case of a test, "module::test[id]" for one case): whole runs in processes of their own and long
# fuzzes whose behaviour a faster test of the fast tier checks as well.
SLOW_TESTS = frozenset(
    {
        # a whole run in a process onto a small tmpfs; the fast tier keeps the runs that cannot
        # write a plot or their summary (test_a_plot_..., test_a_summary_...)
        "sil/test_run_folder.py::test_a_full_disk_names_the_file_and_leaves_no_empty_file",
        # 100k ticks under tracemalloc; test_tracemalloc_sees_no_growth_from_ecu_lines stays
        "ecu/test_allocation_and_integers.py::test_100k_ticks_do_not_grow_allocated_blocks",
        # the plant and the ECU as processes through the adapter's pty; the adapter's frames both
        # ways and a lockstep run over a bus (protocol/test_node.py, test_run_bus.py) stay
        "protocol/test_slcan_device.py::"
        "test_a_lockstep_plant_flies_the_ecu_through_the_adapter_as_over_a_bus",
        # hypothesis, 20 odd values for each of the 100 and more options;
        # test_the_fuzz_covers_the_commands_options stays
        "test_cli_options_fuzz.py::test_an_odd_value_is_taken_or_refused_naming_the_option",
        # 3000 examples each; test_rounding_ties_go_to_even and the C slave's writes stay
        "xcp/test_c_slave.py::test_products_and_quotients_are_the_hosts_doubles",
        "xcp/test_c_slave.py::test_rounding_to_an_integer_is_pythons_round",
        # the same writes at other rates and presets; [default] stays
        "xcp/test_c_slave.py::test_every_parameter_is_written_alike[reproducing]",
        "xcp/test_c_slave.py::test_every_parameter_is_written_alike[64Hz]",
        "xcp/test_c_slave.py::test_every_parameter_is_written_alike[250Hz]",
    }
)
# Tests that assert a figure of the machine's pace (a rate, a real-time factor, microseconds per
# tick): a loaded or slow machine fails them with nothing wrong in the code.
MACHINE_SPEED_TESTS = frozenset(
    {
        "plant/test_steady_line_and_bench.py::test_sil_bench_plant_reports_both_plants",
        "service/test_bench.py::test_bench_service_quick",
        "sil/test_bench.py::test_sil_bench_reports_every_run_and_the_loop_without_start_up",
    }
)
TESTS = Path(__file__).resolve().parent


def _named_tests_missing() -> list[str]:
    """Entries of SLOW_TESTS and MACHINE_SPEED_TESTS whose module does not define the test (a
    renamed test would otherwise leave its tier unnoticed)."""
    missing = []
    for entry in sorted(SLOW_TESTS | MACHINE_SPEED_TESTS):
        module, _, test = entry.partition("::")
        path = TESTS / module
        name = test.split("[", 1)[0]
        if not path.is_file() or f"def {name}(" not in path.read_text():
            missing.append(entry)
    return missing


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    missing = _named_tests_missing()
    if missing:
        raise pytest.UsageError(f"tests/conftest.py names tests that are not there: {missing}")
    for item in items:
        module = item.path.relative_to(TESTS).as_posix()
        test = f"{module}::{getattr(item, 'originalname', item.name)}"
        case = f"{module}::{item.name}"
        if module in SLOW_MODULES or test in SLOW_TESTS or case in SLOW_TESTS:
            item.add_marker(pytest.mark.slow)
        if test in MACHINE_SPEED_TESTS or case in MACHINE_SPEED_TESTS:
            item.add_marker(pytest.mark.machine_speed)
