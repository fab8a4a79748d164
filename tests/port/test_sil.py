"""The C ECU in the SIL: `sil run --ecu-impl c` (the ECU process runs `sil ecu --impl c`) gives a
can.log byte-identical to the Python ECU's, in lockstep over a bus and in process."""

import json
import os
from pathlib import Path

import pytest

SCENARIO = """
description = "short MRAC staircase with a pump fault, for the C port tests"
duration_s = 2.5
[plant]
model = "aero"
[controller]
kind = "mrac"
preset = "sec5_3_mrac_aero"
params = { limiters_on = 1, dead_zone_on = 1, speed_noise_rpm = 20, rate_window_s = 0.05 }
[command]
base = 0
[[command.component]]
kind = "staircase"
levels = [90, 95, 86]
step_s = 0.8
[[fault]]
time_s = 1.2
target = "PUMP_EFFECTIVENESS"
value = 0.7
"""


def _run(sil, tmp_path: Path, impl: str, *mode: str) -> bytes:
    scenario = tmp_path / "short.toml"
    scenario.write_text(SCENARIO)
    out = tmp_path / f"{impl}-{'-'.join(mode) or 'lockstep'}"
    done = sil(
        "run", str(scenario), *mode, "--out", str(out), "--no-plots", "--seed", "3",
        "--ecu-impl", impl, timeout=240,
    )  # fmt: skip
    ecu_log = out / "ecu.log"
    assert done.returncode == 0, done.stderr + (ecu_log.read_text() if ecu_log.exists() else "")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["missed_ticks"] == 0
    return (out / "can.log").read_bytes()


@pytest.mark.slow
def test_lockstep_can_log_is_byte_identical_with_the_c_ecu(
    tmp_path, first_difference, sil, udp_spec
):
    python_log = _run(sil, tmp_path, "python", "--bus", udp_spec())
    c_log = _run(sil, tmp_path, "c", "--bus", udp_spec())
    assert len(c_log.splitlines()) > 1000
    assert first_difference(c_log, python_log) is None


def test_inproc_can_log_is_byte_identical_with_the_c_ecu(tmp_path, first_difference, sil):
    python_log = _run(sil, tmp_path, "python", "--mode", "inproc")
    c_log = _run(sil, tmp_path, "c", "--mode", "inproc")
    assert first_difference(c_log, python_log) is None


def test_sil_ecu_without_a_compiler_says_so(tmp_path, sil):
    env = {
        **os.environ,
        "CC": "",
        "PATH": str(tmp_path),  # no compiler on it
        "ECU_PORT_BUILD_DIR": str(tmp_path / "build"),  # nothing built yet
    }
    done = sil(
        "ecu", "--bus", "virtual:port-test", "--impl", "c", "--ticks", "1", env=env, timeout=240
    )
    assert done.returncode == 2
    assert "sil ecu: --impl c: no C compiler found" in done.stderr


def test_sil_bench_port_reports_the_in_process_cases():
    """`sil bench port`'s SIL part (quick: 30 s): every case's real-time factor, and the shares
    of the compiled run's parts, which are parts of one whole."""
    from sil.bench import port as port_bench

    figures = port_bench.sil_figures(quick=True)
    for key in ("c_ecu", "c_ecu_python_loop", "python_ecu"):
        assert figures[f"sil_inproc_realtime_factor_{key}"] > 0
        assert figures[f"sil_inproc_cpu_realtime_factor_{key}"] > 0
    parts = [v for k, v in figures.items() if k.startswith("sil_c_ecu_cumulative_pct_")]
    assert len(parts) == 5 and all(0 <= p <= 100 for p in parts)
    assert figures["sil_c_ecu_cumulative_pct_compiled_loop"] > 0
    assert sum(parts) <= 100.5  # (the parts do not nest)
    assert isinstance(figures["sil_inproc_target_met"], bool)
