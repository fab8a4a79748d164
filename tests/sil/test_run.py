"""sil run end to end: in one process and as processes over a bus; determinism; robustness."""

import functools
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import can
import numpy as np
import pytest

from protocol.codec import Codec
from sil.analysis.metrics import load_trace

SCENARIO = """
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


def _scenario(tmp_path: Path, duration: float = 3.0) -> Path:
    path = tmp_path / "short.toml"
    path.write_text(SCENARIO.format(duration=duration))
    return path


@pytest.fixture
def sil(sil):
    """tests/conftest.py's ``sil`` with 240 s for a command unless a test gives its own."""
    return functools.partial(sil, timeout=240)


def _no_nodes_left(spec: str) -> bool:
    found = subprocess.run(["pgrep", "-f", f"--bus {spec}"], capture_output=True, text=True)
    return found.stdout.strip() == ""


def test_inproc_run_writes_everything(tmp_path, sil):
    out = tmp_path / "run"
    result = sil(
        "run",
        str(_scenario(tmp_path)),
        "--mode",
        "inproc",
        "--out",
        str(out),
        "--json",
        "--log-format",
        "blf",
    )
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary == json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["abort_reason"] is None
    assert summary["sim_time_s"] == pytest.approx(3.01)
    assert summary["missed_ticks"] == 0
    assert 0 < summary["bus_load_pct"] < 15
    assert summary["faults_injected"][0]["target"] == 1  # PUMP_EFFECTIVENESS
    for key in (
        "realtime_factor",
        "frames",
        "tracking_rms_pct",
        "max_egt_K",
        "egt_limit_time_s",
        "faults",
        "estimates",
        "wall_time_s",
    ):
        assert key in summary
    assert set(summary["estimates"]) == {"Ap_row2", "Lambda", "Theta_row2", "Kx", "Kr", "Kf"}
    trace = load_trace(out / "trace.csv")
    assert len(trace["time"]) == 301
    assert trace["command"][150] == 92.0 and trace["command"][250] == 88.0
    # the engine answers the steps: up after 1 s, down after 2 s
    assert trace["speed_true"][190] > trace["speed_true"][90] + 0.5
    assert trace["speed_true"][290] < trace["speed_true"][190] - 1.0
    frames = list(can.CanutilsLogReader(str(out / "can.log")))
    assert len(frames) == summary["frames"]
    assert len(list(can.BLFReader(str(out / "can.blf")))) == summary["frames"]
    db = Codec().database
    sensors = [
        db.decode_message(f.arbitration_id, f.data) for f in frames if f.arbitration_id == 0x100
    ]
    assert [s["SensorTick"] for s in sensors[:301]] == list(range(301))
    assert {p.name for p in out.glob("*.png")} >= {
        "speed.png",
        "egt.png",
        "estimates.png",
        "gains.png",
    }


@pytest.mark.slow
def test_lockstep_over_udp_is_reproducible_byte_for_byte(tmp_path, first_difference, sil, udp_spec):
    scenario = _scenario(tmp_path)
    logs = []
    for i in range(2):
        out = tmp_path / f"run{i}"
        spec = udp_spec()
        result = sil(
            "run", str(scenario), "--bus", spec, "--out", str(out), "--no-plots", "--seed", "7"
        )
        assert result.returncode == 0, result.stderr + (out / "ecu.log").read_text()
        summary = json.loads((out / "summary.json").read_text())
        assert summary["missed_ticks"] == 0 and summary["bus"] == spec
        assert 0.1 < summary["startup_s"] < summary["wall_time_s"]  # the node processes' start
        ecu = summary["nodes"]["ecu"]  # the node's own figures; no periods in lockstep
        assert ecu["frames_received"] > 0 and ecu["guard_timeouts"] == 0 and "periods" not in ecu
        logs.append((out / "can.log").read_bytes())
        assert _no_nodes_left(spec)
    assert first_difference(logs[0], logs[1]) is None
    # the in-process run goes through the same codec and lockstep rules: the same frames
    out = tmp_path / "inproc"
    assert (
        sil(
            "run", str(scenario), "--mode", "inproc", "--out", str(out), "--no-plots", "--seed", "7"
        ).returncode
        == 0
    )
    assert first_difference((out / "can.log").read_bytes(), logs[0]) is None


def test_real_time_run_is_paced_by_the_wall_clock_and_reports_jitter(tmp_path, sil, udp_spec):
    out = tmp_path / "rt"
    result = sil(
        "run", str(_scenario(tmp_path)), "--mode", "realtime", "--bus", udp_spec(),
        "--out", str(out), "--no-plots",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["mode"] == "realtime"
    assert summary["realtime_factor"] < 1.1  # paced: never faster than the wall clock
    for node in ("ecu", "plant"):
        stats = summary["nodes"][node]
        # the plant runs the 3 s at 100 Hz; the ECU from its own start, before the plant's
        assert 250 <= summary["nodes"]["plant"]["periods"] <= 320 <= stats["periods"] + 70, stats
        assert stats["overruns"] >= 0 and stats["frames_received"] > 0
        jitter = stats["jitter_ms"]
        assert 0.0 <= jitter["p50"] <= jitter["p99"] <= jitter["max"]
    assert not list(out.glob(".*-stats.json"))  # taken into the summary


def _start_run(sil_process, tmp_path: Path, spec: str) -> tuple[subprocess.Popen, Path]:
    out = tmp_path / "run"
    proc = sil_process(
        "run", str(_scenario(tmp_path, duration=300)), "--bus", spec, "--out", str(out),
        "--no-plots",
    )  # fmt: skip
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        trace = out / "trace.csv"
        if trace.exists() and trace.stat().st_size > 200_000:
            return proc, out
        time.sleep(0.2)
    proc.kill()
    raise AssertionError("the run did not get going within 120 s")


def _kill_node(spec: str, node: str) -> None:
    found = subprocess.run(
        ["pgrep", "-f", f"sil.cli {node} --bus {spec}"], capture_output=True, text=True
    ).stdout.split()
    assert found, f"no {node} process for {spec}"
    for pid in found:
        os.kill(int(pid), signal.SIGKILL)


@pytest.mark.slow
@pytest.mark.parametrize("victim", ["plant", "ecu"])
def test_a_killed_node_aborts_the_run_and_keeps_the_records(
    tmp_path, victim, sil_process, udp_spec
):
    spec = udp_spec()
    proc, out = _start_run(sil_process, tmp_path, spec)
    _kill_node(spec, victim)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "aborted"
    assert f"{victim} process exited" in summary["abort_reason"]
    assert summary["sim_time_s"] > 1.0
    assert len(load_trace(out / "trace.csv")["time"]) > 100
    assert _no_nodes_left(spec)
    frames = list(can.CanutilsLogReader(str(out / "can.log")))
    db = Codec().database
    if victim == "plant":
        # the ECU noticed the lost sensor frames and went to FAULT (mode 4) with pump off
        status = [db.decode_message(0x200, f.data) for f in frames if f.arbitration_id == 0x200]
        assert status[-1]["EcuMode"] == "FAULT"
        ecu_log = (out / "ecu.log").read_text()
        assert "mode" in ecu_log
    else:
        # the plant's watchdog removed pump power: no fuel at the end
        truth = [db.decode_message(0x301, f.data) for f in frames if f.arbitration_id == 0x301]
        assert truth[-1]["FuelFlow"] == 0.0


@pytest.mark.slow
def test_ctrl_c_stops_everything_and_keeps_the_records(tmp_path, sil_process, udp_spec):
    spec = udp_spec()
    proc, out = _start_run(sil_process, tmp_path, spec)
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=60)
    assert proc.returncode == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "aborted" and "interrupted" in summary["abort_reason"]
    assert _no_nodes_left(spec)


def test_bad_scenario_is_refused_before_anything_starts(tmp_path, sil):
    bad = tmp_path / "bad.toml"
    bad.write_text("duration_s = 5\n[controller]\nkind = 'fuzzy'\n[command]\n")
    result = sil("run", str(bad), "--out", str(tmp_path / "out"))
    assert result.returncode == 2
    assert "bad.toml: field 'controller.kind'" in result.stderr
    assert not (tmp_path / "out").exists()


def test_a_bad_parameter_is_refused_before_any_process_or_file(tmp_path, sil, udp_spec):
    spec = udp_spec()
    bad = tmp_path / "bad.toml"
    text = SCENARIO.format(duration=3.0).replace("rate_window_s = 0.05", "rate_window_s = 1000.0")
    bad.write_text(text)
    result = sil("run", str(bad), "--out", str(tmp_path / "out"), "--bus", spec)
    assert result.returncode == 2
    assert "rate_window_s=1000.0: must span at least two ticks" in result.stderr
    assert len(result.stderr.splitlines()) == 1
    assert _no_nodes_left(spec)
    assert not (tmp_path / "out").exists()


def test_replay_into_the_ecu_finds_no_difference_and_then_the_changed_parameter(tmp_path, sil):
    out = tmp_path / "run"
    assert (
        sil(
            "run", str(_scenario(tmp_path)), "--mode", "inproc", "--out", str(out), "--no-plots"
        ).returncode
        == 0
    )
    same = sil("replay", str(out / "can.log"), "--into-ecu", "--json")
    assert same.returncode == 0, same.stderr
    report = json.loads(same.stdout)
    assert report["ticks"] == 301 and report["frames_compared"] > 600
    assert report["frames_differing"] == 0 and report["first_divergent_tick"] is None
    assert report["frames_missing"] == report["frames_extra"] == 0
    changed = sil(
        "replay",
        str(out / "can.log"),
        "--into-ecu",
        "--param",
        "gamma_r=0.3",
        "--out",
        str(tmp_path / "cmp"),
        "--json",
    )
    report = json.loads(changed.stdout)
    assert report["frames_differing"] > 0 and report["first_divergent_tick"] >= 0
    assert report["max_difference"]["Gain_Kr"] > 0
    assert (tmp_path / "cmp" / "into_ecu.png").exists()
    assert json.loads((tmp_path / "cmp" / "report.json").read_text()) == report


def test_commissioning_from_identify_reaches_the_ecu(tmp_path, sil):
    commission = tmp_path / "engine.json"
    commission.write_text(
        json.dumps(
            {
                "format": "turbojet-sil commissioning 1",
                "trim_N_pct": 89.68,
                "trim_V": 11.56,
                "Ap_row2": [-1.8054, -2.336],
                "Lambda": 4.822,
                "Theta_row2": [-0.1835, -0.0001],
            }
        )
    )
    out = tmp_path / "run"
    result = sil(
        "run",
        str(_scenario(tmp_path, duration=2.0)),
        "--mode",
        "inproc",
        "--out",
        str(out),
        "--no-plots",
        "--commission",
        str(commission),
        "--json",
    )
    assert result.returncode == 0, result.stderr
    trace = load_trace(out / "trace.csv")
    # the telemetry shows the commissioned estimates and the matching gains of eq. 5.9
    assert trace["Est_Lambda"][30] == pytest.approx(4.822, rel=0.01)
    assert trace["Gain_Kx1"][30] == pytest.approx(-4.809, rel=0.02)
    assert trace["Gain_Kr"][30] == pytest.approx(5.185, rel=0.02)
    commission.write_text('{"format": "turbojet-sil commissioning 1", "Lambda": -1}')
    bad = sil(
        "run",
        str(_scenario(tmp_path)),
        "--mode",
        "inproc",
        "--out",
        str(out),
        "--commission",
        str(commission),
    )
    assert bad.returncode == 2 and "engine.json: field 'trim_N_pct'" in bad.stderr


def test_compare_two_runs(tmp_path, sil):
    mrac = _scenario(tmp_path)
    pid = tmp_path / "pid.toml"
    pid.write_text(
        mrac.read_text().replace('kind = "mrac"\npreset = "sec5_3_mrac_aero"\n', 'kind = "pid"\n')
    )
    for name, path in (("a", mrac), ("b", pid)):
        assert (
            sil(
                "run", str(path), "--mode", "inproc", "--out", str(tmp_path / name), "--no-plots"
            ).returncode
            == 0
        )
    result = sil("compare", str(tmp_path / "a"), str(tmp_path / "b"), "--json")
    assert result.returncode == 0, result.stderr
    table = json.loads(result.stdout)
    rows = {r["field"]: (r["a"], r["b"]) for r in table["rows"]}
    a = json.loads((tmp_path / "a" / "summary.json").read_text())
    b = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert rows["tracking_rms_pct"] == (a["tracking_rms_pct"], b["tracking_rms_pct"])
    assert (tmp_path / "b" / "compare.png").stat().st_size > 10_000
    missing = sil("compare", str(tmp_path / "a"), str(tmp_path / "nowhere"))
    assert missing.returncode == 2 and "nowhere: no such folder" in missing.stderr


OPEN_THERMOCOUPLE = """
duration_s = 3
[plant]
model = "aero"
[controller]
preset = "default"
[command]
base = 85
[[fault]]
time_s = 1.0
target = "EGT_OPEN_CIRCUIT"
value = 1
"""


def test_an_open_thermocouple_reading_its_burnout_value_is_flagged(tmp_path):
    """The plant's open thermocouple reads the EGT signal's full scale (1638.3 K, the
    amplifier's upscale burnout); the ECU flags EGT_OPEN after its persistence time."""
    from ecu.params import EGT_FULL_SCALE_K, EcuParams
    from sil import scenario as scenarios
    from sil.run.runner import RunOptions, run

    path = tmp_path / "open.toml"
    path.write_text(OPEN_THERMOCOUPLE)
    summary = run(
        RunOptions(scenarios.load(path), tmp_path / "r", mode="inproc", plots=False, progress=False)
    )
    assert EcuParams().egt_open_high_k < EGT_FULL_SCALE_K
    assert summary["max_egt_K"] == pytest.approx(EGT_FULL_SCALE_K, abs=0.1)  # the EGT frames
    egt = load_trace(tmp_path / "r" / "trace.csv")["EGT"]
    assert np.all(egt[:90] < 1200.0)  # before the fault (1 s at 100 Hz)
    flagged = [f["time_s"] for f in summary["faults"] if f["fault"] == "EGT_OPEN"]
    assert flagged and 1.0 < flagged[0] <= 1.0 + EcuParams().egt_fault_time_s + 0.02


def test_a_node_that_cannot_come_up_says_why_in_the_abort(tmp_path, sil, udp_spec):
    # an emulator that is there but fails at once: the run's checks find it, the ECU node of
    # --ecu-impl pil stops before it is ready
    spec = udp_spec()
    out = tmp_path / "out"
    shim = tmp_path / "bin" / "qemu-system-arm"
    shim.parent.mkdir()
    shim.write_text("#!/bin/sh\necho 'qemu-system-arm: no such board here' >&2\nexit 1\n")
    shim.chmod(0o755)
    env = {**os.environ, "PATH": f"{shim.parent}{os.pathsep}{os.environ['PATH']}"}
    result = sil(
        "run", str(_scenario(tmp_path)), "--out", str(out), "--bus", spec, "--ecu-impl", "pil",
        timeout=120, env=env,
    )  # fmt: skip
    assert result.returncode == 1, result.stderr
    summary = json.loads((out / "summary.json").read_text())
    reason = summary["abort_reason"]
    assert reason.startswith("ecu process did not come up: ") and reason.endswith("(see ecu.log)")
    assert "no such board here" in reason, reason
    assert _no_nodes_left(spec)
