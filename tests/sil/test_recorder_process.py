"""The recorder in a process of its own (in-process runs): the same files as the recorder in
process, every frame kept on Ctrl-C, and a dead recorder process ends the run cleanly."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest

from protocol.codec import Codec
from sil import scenario
from sil.record.recorder import Recorder
from sil.run import runner
from sil.run.recorder_process import (
    BATCH_FRAMES,
    NICE,
    RecorderFailed,
    RecorderProcess,
    _patiently,
)
from sil.run.runner import RunOptions

SCENARIO = """
description = "MRAC staircase with a pump failure, for the recorder process tests"
duration_s = {duration}
[plant]
model = "aero"
[controller]
kind = "mrac"
preset = "sec5_3_mrac_aero"
[command]
base = 0
[[command.component]]
kind = "staircase"
levels = [90, 93, 87]
step_s = 2
[[fault]]
time_s = 3.0
target = "PUMP_EFFECTIVENESS"
value = 0.5
"""


def _scenario(tmp_path: Path, duration: float) -> Path:
    path = tmp_path / "recorder.toml"
    path.write_text(SCENARIO.format(duration=duration))
    return path


class _InProcess:
    """The Recorder where the runner would start the recorder process."""

    def open(self, out_dir, period_s, *, commands=None, channel="vcan0", wait=True):  # noqa: ANN001, ARG002
        return Recorder(out_dir, Codec(), period_s, commands=commands, channel=channel)

    def discard(self) -> None:
        pass


def _recorder_processes(parent: int | None = None) -> list[int]:
    """Recorder processes alive (of ``parent`` only, if given: other runs may share the
    machine)."""
    where = ["-P", str(parent)] if parent is not None else []
    found = subprocess.run(
        ["pgrep", *where, "-f", "sil.run.recorder_process"], capture_output=True, text=True
    )
    return [int(pid) for pid in found.stdout.split()]


def _alive(pids: list[int]) -> list[int]:
    return [pid for pid in pids if Path(f"/proc/{pid}").exists()]


# what differs from one run to the next of the same scenario: its times, its bus and its senders
PER_RUN = ("wall_time_s", "realtime_factor", "startup_s", "bus", "run_id", "nodes", "run_senders",
           "tick0_utc")  # fmt: skip


@pytest.mark.parametrize("mode", ["inproc", "lockstep"])
def test_the_files_are_those_of_the_recorder_in_process(tmp_path, monkeypatch, mode):
    s = scenario.load(_scenario(tmp_path, 8.0))
    offloaded = runner.run(RunOptions(s, tmp_path / "process", mode=mode, plots=False))
    monkeypatch.setattr(runner, "RecorderProcess", _InProcess)
    local = runner.run(RunOptions(s, tmp_path / "local", mode=mode, plots=False))
    for name in ("can.log", "trace.csv"):
        a = (tmp_path / "process" / name).read_bytes()
        assert a == (tmp_path / "local" / name).read_bytes(), name
    for summary in (offloaded, local):  # (on a bus, the node processes' own counts end when
        # they are stopped: an ECU left 2 s without sensor frames ticks once on its own clock)
        for key in PER_RUN:
            summary.pop(key, None)
    assert offloaded == local
    assert offloaded["status"] == "completed" and offloaded["frames"] > 3000
    assert offloaded["faults_injected"] and offloaded["missed_ticks"] == 0
    frames = list(can.CanutilsLogReader(str(tmp_path / "process" / "can.log")))
    assert len(frames) == offloaded["frames"]


@pytest.mark.slow
def test_ctrl_c_keeps_every_frame_recorded(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sil.cli", "run", str(_scenario(tmp_path, 300.0))]
        + ["--mode", "inproc", "--out", str(out), "--no-plots"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    trace = out / "trace.csv"
    while not (trace.exists() and trace.stat().st_size > 400_000):  # a chunk or two is written
        assert time.monotonic() < deadline and proc.poll() is None, proc.stderr
        time.sleep(0.05)
    recorders = _recorder_processes(proc.pid)
    assert len(recorders) == 1
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=60)
    assert proc.returncode == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "aborted" and "interrupted" in summary["abort_reason"]
    # the loop outruns the recorder: the Ctrl-C may come after its last tick, while the recorder
    # finishes its files; the run is aborted either way, and every frame is kept
    assert 20.0 < summary["sim_time_s"] <= 300.01  # (a run that ended reports its last tick)
    # every frame the nodes exchanged up to the interrupt is in the log, no tick left out
    frames = list(can.CanutilsLogReader(str(out / "can.log")))
    assert len(frames) == summary["frames"]
    db = Codec().database
    ticks = [
        db.decode_message(0x100, f.data)["SensorTick"] for f in frames if f.arbitration_id == 0x100
    ]
    assert ticks == list(range(len(ticks))) and len(ticks) > 2000
    # the recorder process is not waited for once its files are closed: it leaves on its own,
    # within moments on an idle machine, later on a loaded one
    deadline = time.monotonic() + 10.0
    while _alive(recorders) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert _alive(recorders) == []


def test_a_ctrl_c_while_the_recorder_finishes_waits_for_it_once_and_is_kept():
    calls = []

    def wait():
        calls.append(len(calls))
        if len(calls) == 1:
            raise KeyboardInterrupt
        return "totals"

    interrupted: list[KeyboardInterrupt] = []
    assert _patiently(wait, interrupted) == "totals"  # waited again, the interrupt kept
    assert calls == [0, 1] and len(interrupted) == 1
    calls.clear()
    with pytest.raises(KeyboardInterrupt):  # a second Ctrl-C is not held off
        _patiently(wait, interrupted)


def test_a_dead_recorder_process_is_reported_and_what_it_wrote_stays(tmp_path):
    codec = Codec()
    sensors = codec["PlantSensors"]
    recorder = RecorderProcess().open(tmp_path, 0.01)
    sensors.pack_raw([0, 100_000, 10_000])
    recorder.record(sensors.frame_id, sensors.data)
    deadline = time.monotonic() + 30
    while not (tmp_path / "trace.csv").exists():  # the child's recorder is up
        assert time.monotonic() < deadline
        time.sleep(0.01)
    os.kill(recorder._child.pid, signal.SIGKILL)
    with pytest.raises(RecorderFailed, match="exited with code -9"):
        for k in range(2 * BATCH_FRAMES):
            sensors.pack_raw([k % 65536, 100_000, 10_000])
            recorder.record(sensors.frame_id, sensors.data)
            time.sleep(0.0 if k % 64 else 0.001)
    with pytest.raises(RecorderFailed):
        recorder.close()
    assert recorder.totals()["frames"] >= BATCH_FRAMES  # the figures known here
    assert (tmp_path / "can.log").exists()


def test_a_run_whose_recorder_process_dies_is_aborted_with_the_reason(tmp_path, monkeypatch):
    s = scenario.load(_scenario(tmp_path, 60.0))

    class Dying(RecorderProcess):
        def record(self, frame_id, data, wall_s=None):  # noqa: ANN001
            if self.frames == 10_000:
                os.kill(self._child.pid, signal.SIGKILL)
                self._child.wait()
            super().record(frame_id, data, wall_s)

    monkeypatch.setattr(runner, "RecorderProcess", Dying)
    summary = runner.run(RunOptions(s, tmp_path / "run", mode="inproc", plots=False))
    assert summary["status"] == "aborted"
    assert summary["abort_reason"] == "the recorder process exited with code -9"
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["status"] == "aborted"


def test_a_discarded_recorder_process_writes_nothing_and_goes(tmp_path):
    recorder = RecorderProcess()
    pid = recorder._child.pid
    recorder.discard()
    assert recorder._child.returncode == 0
    assert pid not in _recorder_processes()
    assert list(tmp_path.iterdir()) == []


def test_the_recorder_process_yields_the_cores_to_the_nodes_once_it_is_set_up(tmp_path):
    recorder = RecorderProcess()
    stat = Path(f"/proc/{recorder._child.pid}/stat")
    try:  # its imports at the run's priority (on a loaded machine the lowest would crawl)
        assert int(stat.read_text().split()[18]) == os.getpriority(os.PRIO_PROCESS, 0)
        recorder.open(tmp_path, 0.01)  # its Recorder made: from now on the lowest priority
        deadline = time.monotonic() + 10
        while int(stat.read_text().split()[18]) != min(
            19, os.getpriority(os.PRIO_PROCESS, 0) + NICE
        ):
            assert time.monotonic() < deadline
            time.sleep(0.01)
    finally:
        recorder.close()


def test_a_recorder_that_cannot_write_names_the_file_and_the_run_is_aborted(tmp_path, capfd):
    s = scenario.load(_scenario(tmp_path, 20.0))
    out = tmp_path / "run"
    (out / "can.log").mkdir(parents=True)  # where the log should go
    summary = runner.run(RunOptions(s, out, mode="inproc", plots=False))
    assert summary["status"] == "aborted"
    assert summary["abort_reason"] == f"{out / 'can.log'}: cannot write: Is a directory"
    assert summary["write_errors"] == [summary["abort_reason"]]
    assert "can.log" not in summary["kept"] and "summary.json" in summary["kept"]
    assert capfd.readouterr().err == ""  # the run says why, the recorder process says nothing


def test_open_returns_once_the_child_has_made_its_recorder(tmp_path):
    """Made before the run begins, as the in-process Recorder: its files exist when open()
    returns (the child's start-up is the set-up's, not the run's)."""
    recorder = RecorderProcess()
    recorder.open(tmp_path, 0.01)
    try:
        assert (tmp_path / "can.log").exists()
        assert (tmp_path / "trace.csv").exists()
    finally:
        recorder.close()
    assert recorder.totals()["frames"] == 0


def test_a_child_not_waited_for_still_answers_at_close(tmp_path):
    """open(wait=False): the child's start-up overlaps what comes next; close reads its READY
    before its figures."""
    recorder = RecorderProcess()
    recorder.open(tmp_path, 0.01, wait=False)
    recorder.close()
    assert recorder.totals()["frames"] == 0 and (tmp_path / "can.log").exists()
