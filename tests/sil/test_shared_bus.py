"""Two `sil run` on one bus at once: each completes, with the can.log of a run alone."""

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from protocol.run_tag import claim_tag, tag_file

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
step_s = 5
[[fault]]
time_s = 7.5
target = "PUMP_EFFECTIVENESS"
value = 0.8
"""


@pytest.fixture
def env(tmp_path, monkeypatch) -> dict[str, str]:
    """The runs' environment: tags claimed under a runtime folder of the test's own."""
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    return {**os.environ}


def _run(
    sil_process, tmp_path: Path, name: str, spec: str, env: dict, duration: float
) -> subprocess.Popen:
    scenario = tmp_path / f"short-{duration:g}.toml"
    scenario.write_text(SCENARIO.format(duration=duration))
    args = ["run", str(scenario), "--bus", spec, "--out", str(tmp_path / name), "--no-plots"]
    return sil_process(*args, "--seed", "7", stdout=subprocess.DEVNULL, env=env)


def _summary(tmp_path: Path, name: str) -> dict:
    return json.loads((tmp_path / name / "summary.json").read_text())


@pytest.mark.slow
def test_two_runs_on_one_bus_each_log_what_a_run_alone_logs(tmp_path, env, sil_process, udp_spec):
    spec = udp_spec()
    solo = _run(sil_process, tmp_path, "solo", spec, env, 30.0)
    assert solo.wait(120) == 0, solo.stderr.read()
    started = time.monotonic()
    runs = {name: _run(sil_process, tmp_path, name, spec, env, 30.0) for name in ("a", "b")}
    for name, proc in runs.items():
        assert proc.wait(120) == 0, f"{name}: {proc.stderr.read()}"
    elapsed = time.monotonic() - started
    alone = (tmp_path / "solo" / "can.log").read_bytes()
    summaries = {name: _summary(tmp_path, name) for name in ("solo", "a", "b")}
    assert summaries["solo"]["run_tag"] == 0 and summaries["solo"]["foreign_frames"] == 0
    assert sorted(summaries[n]["run_tag"] for n in ("a", "b")) == [0, 1]
    assert summaries["a"]["run_id"] != summaries["b"]["run_id"]
    for name in ("a", "b"):
        summary = summaries[name]
        assert list(summary)[:2] == ["status", "abort_reason"]
        assert summary["status"] == "completed" and summary["missed_ticks"] == 0
        assert (tmp_path / name / "can.log").read_bytes() == alone, name
        assert summary["frames"] == summaries["solo"]["frames"]
        # the runs overlapped: each heard the other's frames (and beacon), and dropped them
        assert summary["foreign_frames"] > 0 and summary["foreign_runs"] == 1, summary
        assert summary["unknown_ids"] == {} and summary["wrong_length"] == {}
    for name in ("a", "b"):  # (pytest -s) what each of the run's nodes dropped
        summary = summaries[name]
        nodes = {n: f["foreign_frames"] for n, f in summary["nodes"].items()}
        print(f"{elapsed:.1f} s, run {name} (tag {summary['run_tag']}): foreign frames", end=" ")
        print(f"{summary['foreign_frames']} (recorder), {nodes}")
    with claim_tag(spec) as claim:  # both runs gave their tags back
        assert claim.tag == 0


@pytest.mark.slow
def test_a_killed_run_gives_its_tag_back(tmp_path, env, sil_process, udp_spec):
    spec = udp_spec()
    proc = _run(sil_process, tmp_path, "killed", spec, env, 600.0)
    deadline = time.monotonic() + 60
    while not tag_file(spec, 0).exists():  # the run's claim (this test's folder: nobody else's)
        assert time.monotonic() < deadline and proc.poll() is None, proc.stderr.read()
        time.sleep(0.05)
    with claim_tag(spec) as claim:
        assert claim.tag == 1
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    with claim_tag(spec) as claim:
        assert claim.tag == 0
