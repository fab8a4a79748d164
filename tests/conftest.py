"""Helpers every test folder may use, as fixtures: the `sil` command in a process of its own
(``sil``, ``sil_process``), a loopback bus of a test's own (``udp_spec``, ``udp_group``), the first
difference of two logs."""

from __future__ import annotations

import json
import os
import random
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import can  # noqa: F401  whole, with its MF4 classes: the tests' second reader of our MF4 logs
import pytest
from hypothesis import settings

# Property tests compute microseconds per example; a deadline would only measure the machine's
# load (the suite runs on every core), so examples have none.
settings.register_profile("suite", deadline=None)
settings.load_profile("suite")

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
# Tests paced by the wall clock or asserting it (real-time nodes and runs, a client keeping pace
# with a lockstep run, a browser on a live page, benches that time): marked realtime, they run
# after the others, one at a time with the machine to themselves (dev.py's second part).
REALTIME_MODULES = frozenset(
    {
        # `sil bench service --quick`: asserts frames/s, round trips/s and µs per tick
        "service/test_bench.py",
        # `sil plant --realtime` + `sil ecu --mode realtime --serial pty`, console
        # start/throttle/stop, asserts start_s < 40
        "service/test_bench_start.py",
        # lockstep run at ~25x real time; a client thread must join and keep pace (ticks[0] < 200,
        # ticks[-1] >= 360, no gaps)
        "service/test_sil_stream.py",
        # `sil bench campaign --quick`: measures runs per minute
        "sil/test_campaign_bench.py",
        # `sil replay --loop` plays a log onto the run's bus in real time
        "sil/test_foreign_frames.py",
        # Playwright/Chromium against the live page; `bench` fixture = real-time plant + ECU + sil
        # gsu
        "gsu/test_browser.py",
        # `bench` fixture / gsu.station(): real-time plant + ECU; asserts answers within 3 s and
        # live-again deadlines
        "gsu/test_masters.py",
        # in-process XCP slave thread served every 10 ms; asserts refused within 0.1 s,
        # SETTLE_S/SILENT_S timing
        "gsu/test_xcp_link.py",
        # `sil plant --realtime` beside `sil ecu --mode realtime`, the pyXCP session of
        # docs/calibration.md
        "xcp/test_calibration_doc.py",
        # `sil plant --realtime` + `sil ecu --impl X --mode realtime`; glow test waited with 2 s and
        # 3 s limits
        "xcp/test_logbook_pyxcp.py",
        # pyXCP against `sil ecu --mode realtime` beside `sil plant --realtime --standstill`
        "xcp/test_pyxcp.py",
        # lockstep run at 40x+ real time; the pyXCP master must start DAQ within ~1000 ticks (>=
        # 6000 of 7000) and lose no DTO (a race with wall time)
        "xcp/test_lockstep.py",
    }
)
REALTIME_TESTS = frozenset(
    {
        # benches that measure speed
        # `sil bench plant`: asserts real-time factors > 1 (already MACHINE_SPEED_TESTS)
        "plant/test_steady_line_and_bench.py::test_sil_bench_plant_reports_both_plants",
        # `sil bench sil`: real-time factors, python_tick_us 5..500, plant_us 2..200
        "sil/test_bench.py::test_sil_bench_reports_every_run_and_the_loop_without_start_up",
        # `sil run --mode realtime` at 100 Hz and 1 kHz: missed_ticks == 0, periods within 0.9..1.2x
        "sil/test_realtime_bench.py::test_realtime_bench_reports_each_node_at_each_rate",
        # `sil bench all --only codec,ecu`: runs the codec and ECU timing benches
        "sil/test_bench_all.py::test_all_writes_the_page_with_every_figure_and_target",
        # run_all runs the codec timing bench (asserts only codec_encode_us > 0)
        "sil/test_bench_all.py::test_a_failing_bench_is_reported_and_the_others_still_run",
        # `sil bench codec --quick`: a timing bench (asserts only > 0)
        "test_cli.py::test_bench_codec_json",
        # sil.bench.port.sil_figures: in-process real-time factors (asserts only > 0)
        "port/test_sil.py::test_sil_bench_port_reports_the_in_process_cases",
        # bench.compare_with times ticks (CPU time; asserts only > 0)
        "ecu/test_bench_against.py::test_the_same_firmware_gives_the_same_outputs_and_both_are_timed",
        # bench.compare_with runs its timed rounds too (asserts only the equality flag)
        "ecu/test_bench_against.py::test_a_firmware_that_answers_differently_is_found_out",
        # `sil bench ecu --quick --against HEAD`: times both firmwares
        "ecu/test_bench_against.py::test_the_command_reports_both_figures_and_the_speed_up",
        # real-time runs and nodes
        # `sil run --mode realtime`: realtime_factor < 1.1, 250..320 periods
        "sil/test_run.py::test_real_time_run_is_paced_by_the_wall_clock_and_reports_jitter",
        # `sil run --mode realtime`, node SIGKILLed 1 s in: wall_s within killed-0.3..killed+1.0
        "sil/test_early_end.py::test_a_node_killed_in_a_real_time_run_is_named_with_when_and_why",
        # `sil run --mode realtime --ecu-impl pil` (QEMU), wall_s window as above
        "sil/test_early_end.py::test_the_emulator_killed_under_the_image_in_real_time_ends_the_run_naming_it",
        # in process, but asserts wall_s in [3.0, 4.0) read from perf_counter
        "sil/test_early_end.py::test_a_node_that_failed_is_named_with_its_code_its_last_line_and_when",
        # message "stopped 2.0 s" formed from time.monotonic(): a 50 ms margin
        "sil/test_early_end.py::test_a_real_time_run_short_of_answers_says_when_they_stopped_or_how_far_behind",
        # five `sil run --mode realtime` at once against lockstep (start time within 1 s)
        "sil/test_mode_equivalence.py::test_the_starts_in_real_time_are_the_lockstep_starts",
        # `sil plant --realtime` + `sil ecu --mode realtime --serial pty`, then realtime second ECUs
        # (python, c, pil)
        "sil/test_second_ecu.py::test_a_second_ecu_on_a_live_bench_bus_stays_silent",
        # replay.play: real-time playback at 1 kHz, duration_s >= 0.199
        "sil/test_replay.py::test_playback_timing_and_filter",
        # replay.play of an MF4: real-time playback, duration_s >= 0.099
        "sil/test_mdf.py::test_an_mf4_plays_onto_a_bus",
        # lockstep, but asserts silence 0.5..3.0 s and detection took < 5 s (wall)
        "sil/test_watchdog.py::test_a_stopped_node_aborts_the_run_naming_it",
        # asserts took < 10 s and "stopped ... for 1.x s" (wall)
        "sil/test_watchdog.py::test_a_node_stopped_before_it_is_ready_ends_the_run_naming_it",
        # spawns 2x cores busy spinners; asserts took < 5 s
        "sil/test_lockstep_load.py::test_an_ecu_stopped_on_a_loaded_machine_is_found_and_named_within_5_s",
        # `sil plant --realtime` + `sil ecu --mode realtime --serial pty`, console, sleep(4) then
        # speed check
        "service/test_bench_restart.py::test_a_bench_restart_goes_to_idle_not_to_the_old_throttle",
        # start_ecu() real-time ECU, `sil console --rate 20 --timeout 0.5 live`
        "service/test_console_cli.py::test_live_prints_samples_as_they_come_and_keeps_them_when_the_ecu_goes_away",
        # start_ecu() real-time ECU (default mode)
        "service/test_console_cli.py::test_the_logbook_prints_the_stored_counts_by_name_in_their_units",
        # module fixture ecu_port = start_ecu() real-time ECU
        "service/test_console_cli.py::test_set_refuses_a_value_no_finite_number_naming_the_parameter",
        # start_ecu() real-time ECU twice; 50 Hz stream of 100 Hz ticks
        "service/test_pty.py::test_service_over_a_pty_between_processes_and_a_power_cut",
        # start_ecu() real-time ECU, interactive `sil console`
        "service/test_pty.py::test_interactive_console_on_a_terminal",
        # lockstep ECU, but asserts identify answered within 1.0 s
        "service/test_pty.py::test_a_lockstep_ecu_with_no_plant_serves_its_port",
        # a lockstep ECU, then start_ecu() real-time reader ECU
        "service/test_logbook_at_stop.py::test_an_ecu_stopped_in_the_cool_down_keeps_the_run",
        # start_ecu() real-time ECU, SIGKILL at a random wall time 0.1..1.0 s; >= 1 cut inside a
        # save
        "service/test_storage.py::test_power_cut_of_the_ecu_process_during_saves_over_the_port",
        # asserts port.counters.worst_s < 0.05 (wall time, preemption included)
        "service/test_services.py::test_work_per_tick_is_bounded",
        # `sil plant --realtime --ticks 40` watched on the bus
        "test_cli_robustness.py::test_a_plant_applies_faults_named_as_in_a_scenario",
        # `sil plant --realtime` + `sil ecu --impl c --mode realtime`, pyXCP, sleep(4) then speed
        # check
        "xcp/test_bench_restart.py::test_pyxcp_restart_of_the_c_ecu_goes_to_idle",
        # `sil ecu --impl c --mode realtime --ticks 1` (trivial, but a real-time node)
        "xcp/test_ids.py::test_the_c_node_takes_xcp_ids",
        # real-time plant + ECU; >= 150 samples in 2 s, mean dt 9.5..10.5 ms
        "xcp/test_daq_mf4.py::test_sil_xcp_record_writes_the_a2ls_names_units_and_conversions",
        # lockstep at ~40x; the master must join within ~2000 of 4000 ticks and lose no sample (race
        # with wall time)
        "xcp/test_daq_mf4.py::test_daq_of_a_lockstep_run_into_mf4_is_its_trace",
        # asserts every endpoint answers within 1.0 s
        "gsu/test_requests.py::test_every_endpoint_answers_at_once_when_the_ecu_is_silent",
        # asserts unlock is refused within 1.0 s
        "gsu/test_server.py::test_a_silent_ecu_is_a_refusal_at_once",
        # wall-clock Bridge: asserts 0.18 <= lag < 0.5 s
        "campaign/test_bridge.py::test_bridge_delays_frames_by_ticks_of_the_wall_clock",
        # Bridge thread must forward within recv(0.1)/sleep(0.1) windows
        "campaign/test_bridge.py::test_sensor_ticks_follow_plant_sensors_and_release_delayed_frames_before_the_new_tick",
        # wall-clock Bridge thread; drained with 0.5 s quiet gaps (weak dependence)
        "campaign/test_bridge.py::test_bridge_drops_at_its_rate_flips_bits_and_passes_the_rest_both_ways",
        # `sil bridge --duration 4` paced by the wall clock; 20 frames drained with a 0.5 s gap
        "campaign/test_bridge.py::test_sil_bridge_command_between_two_udp_buses",
        # busy spinners on every core beside a lockstep run: slows whatever runs beside it
        "sil/test_lockstep_load.py::"
        "test_a_lockstep_run_beside_busy_processes_is_the_quiet_machines_run",
    }
)
TESTS = Path(__file__).resolve().parent


def _named_tests_missing() -> list[str]:
    """Modules of SLOW_MODULES and REALTIME_MODULES that are not there, and entries of SLOW_TESTS,
    MACHINE_SPEED_TESTS and REALTIME_TESTS whose module does not define the test (a renamed test
    would otherwise leave its tier unnoticed)."""
    missing = sorted(m for m in SLOW_MODULES | REALTIME_MODULES if not (TESTS / m).is_file())
    for entry in sorted(SLOW_TESTS | MACHINE_SPEED_TESTS | REALTIME_TESTS):
        module, _, test = entry.partition("::")
        path = TESTS / module
        name = test.split("[", 1)[0]
        if not path.is_file() or f"def {name}(" not in path.read_text():
            missing.append(entry)
    return missing


def pytest_configure(config: pytest.Config) -> None:
    # Ctrl-C as in a terminal, for the tests that interrupt a recording or a node: a test run
    # started in the background by a shell without job control inherits Ctrl-C ignored, and so
    # would every process a test starts (Python keeps an ignored SIGINT ignored).
    signal.signal(signal.SIGINT, signal.default_int_handler)


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
        if module in REALTIME_MODULES or test in REALTIME_TESTS:
            item.add_marker(pytest.mark.realtime)
    # The VM's module first: on its own worker for most of the run, beside all the others.
    items.sort(key=lambda item: item.get_closest_marker("vcan") is None)
