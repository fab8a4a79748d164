"""Results never stale: a run into a folder of an earlier one removes what that one wrote (and
only that), its summary states its status first, and `sil compare` refuses incomplete runs."""

import functools
import json
import math
import signal
import subprocess
import time
from pathlib import Path

import can
import pytest

from sil.record import results

SCENARIO = """
duration_s = {duration}
[plant]
model = "aero"
[controller]
kind = "mrac"
preset = "sec5_3_mrac_aero"
params = {{ rate_window_s = {window} }}
[command]
base = 0
[[command.component]]
kind = "staircase"
levels = [90, 92]
step_s = 1
"""


def _scenario(tmp_path: Path, name: str, duration: float = 2.0, window: float = 0.05) -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(SCENARIO.format(duration=duration, window=window))
    return path


@pytest.fixture
def sil(sil):
    """tests/conftest.py's ``sil`` with 240 s for a command unless a test gives its own."""
    return functools.partial(sil, timeout=240)


def _summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def _good_run(sil, tmp_path: Path, out: Path) -> None:
    """A completed in-process run with plots and every extra log format, and two files of the
    user's own in its folder."""
    result = sil(
        "run", str(_scenario(tmp_path, "good")), "--mode", "inproc", "--out", str(out),
        "--log-format", "asc", "--log-format", "blf",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert next(iter(_summary(out))) == "status" and _summary(out)["status"] == "completed"
    written = {p.name for p in out.iterdir()}
    assert {"speed.png", "can.blf", "can.asc", "trace.csv"} <= written
    assert written <= set(results.RUN_FILES)  # every name a run writes is one it clears
    (out / "notes.txt").write_text("mine")
    (out / "mine.png").write_bytes(b"not a plot of the run")


def _only_users_files_and(out: Path, *names: str) -> None:
    assert sorted(p.name for p in out.iterdir()) == sorted(["notes.txt", "mine.png", *names])
    assert (out / "notes.txt").read_text() == "mine"


def _as_it_was(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.iterdir())}


def test_a_run_refused_for_a_bad_parameter_leaves_the_folder_as_it_was(tmp_path, sil):
    out = tmp_path / "run"
    _good_run(sil, tmp_path, out)
    before = _as_it_was(out)
    bad = sil(
        "run", str(_scenario(tmp_path, "bad", window=1000.0)), "--mode", "inproc",
        "--out", str(out),
    )  # fmt: skip
    assert bad.returncode == 2
    assert "rate_window_s=1000.0: must span at least two ticks" in bad.stderr
    assert len(bad.stderr.splitlines()) == 1
    assert _as_it_was(out) == before  # checked before the folder was touched
    assert _summary(out)["status"] == "completed"


def test_a_refused_scenario_file_leaves_the_folder_as_it_was(tmp_path, sil):
    out = tmp_path / "run"
    _good_run(sil, tmp_path, out)
    before = _as_it_was(out)
    broken = tmp_path / "broken.toml"
    broken.write_text("duration_s = 5\n[controller]\nkind = 'fuzzy'\n[command]\n")
    result = sil("run", str(broken), "--out", str(out))
    assert result.returncode == 2 and "field 'controller.kind'" in result.stderr
    assert len(result.stderr.splitlines()) == 1
    assert _as_it_was(out) == before


def test_a_run_failing_once_set_up_began_is_marked_failed(tmp_path, monkeypatch, sil):
    from sil.run import runner

    out = tmp_path / "run"
    _good_run(sil, tmp_path, out)

    def no_plant(*args, **kwargs):
        raise ValueError("no plant today")

    monkeypatch.setattr(runner, "build_plant", no_plant)
    opts = runner.RunOptions(
        _load(_scenario(tmp_path, "good")), out, mode="inproc", plots=False, progress=False
    )
    with pytest.raises(ValueError, match="no plant today"):
        runner.run(opts)
    _only_users_files_and(out, "scenario.toml", "run.json", "summary.json")
    summary = _summary(out)
    assert list(summary)[:2] == ["status", "abort_reason"]
    assert summary["status"] == "failed"
    assert summary["abort_reason"] == "no plant today (before the run began)"
    refused = sil("compare", str(out), str(out))
    assert refused.returncode == 2
    assert f"{out}: incomplete run (status failed: " in refused.stderr
    assert len(refused.stderr.splitlines()) == 1
    # nothing recorded: not comparable even when incomplete runs are allowed
    allowed = sil("compare", str(out), str(out), "--allow-incomplete")
    assert allowed.returncode == 2 and f"{out}: no trace.csv (status failed" in allowed.stderr


def _load(path: Path):
    from sil import scenario

    return scenario.load(str(path))


def _start(sil_process, tmp_path: Path, out: Path) -> subprocess.Popen:
    """A long in-process run without plots or extra formats, once it has written some trace."""
    proc = sil_process(
        "run", str(_scenario(tmp_path, "long", 3000.0)), "--mode", "inproc", "--out", str(out),
        "--no-plots",
    )  # fmt: skip
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if (out / "trace.csv").exists() and (out / "trace.csv").stat().st_size > 500_000:
            # the run's own summary says it is running meanwhile
            assert _summary(out) == {"status": "running", "abort_reason": None, "scenario": "long"}
            return proc
        time.sleep(0.1)
    proc.kill()
    raise AssertionError("the run did not get going within 120 s")


@pytest.mark.slow
def test_an_interrupted_run_is_marked_aborted_and_compare_refuses_it(tmp_path, sil, sil_process):
    out, good = tmp_path / "run", tmp_path / "good"
    _good_run(sil, tmp_path, out)
    _good_run(sil, tmp_path, good)
    proc = _start(sil_process, tmp_path, out)
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=60)
    assert proc.returncode == 1
    summary = _summary(out)
    assert next(iter(summary)) == "status" and summary["status"] == "aborted"
    assert summary["abort_reason"] == "interrupted (Ctrl-C)"
    # its own records kept, the earlier run's plots and other formats gone
    _only_users_files_and(out, "scenario.toml", "run.json", "summary.json", "can.log", "trace.csv")
    frames = list(can.CanutilsLogReader(str(out / "can.log")))
    assert len(frames) == summary["frames"] > 1000
    refused = sil("compare", str(good), str(out))
    assert refused.returncode == 2
    assert refused.stderr == (
        f"sil compare: {out}: incomplete run (status aborted: interrupted (Ctrl-C)); "
        "--allow-incomplete compares what it recorded\n"
    )
    marked = sil("compare", str(good), str(out), "--allow-incomplete", "--json")
    assert marked.returncode == 1
    table = json.loads(marked.stdout)
    assert table["b"] == "long (INCOMPLETE)" and table["a"] == "good"
    assert table["incomplete"] == {"a": None, "b": "status aborted: interrupted (Ctrl-C)"}
    assert {"field": "status", "a": "completed", "b": "aborted"} in table["rows"]
    assert f"{out}: INCOMPLETE run" in marked.stderr


@pytest.mark.slow
def test_a_run_killed_outright_still_says_running(tmp_path, sil, sil_process):
    out = tmp_path / "run"
    _good_run(sil, tmp_path, out)
    proc = _start(sil_process, tmp_path, out)
    proc.kill()
    proc.communicate(timeout=60)
    assert _summary(out)["status"] == "running"
    # and its lock file, no longer locked: the next run into the folder takes it
    _only_users_files_and(
        out, "scenario.toml", "run.json", "summary.json", "can.log", "trace.csv", ".lock"
    )
    refused = sil("compare", str(out), str(out))
    assert refused.returncode == 2
    assert "status running: the run is still going or was killed" in refused.stderr


def test_compare_refuses_a_folder_without_a_run(tmp_path, sil):
    (tmp_path / "empty").mkdir()
    (tmp_path / "odd").mkdir()
    (tmp_path / "odd" / "summary.json").write_text("[1, 2]")
    for folder, why in (
        ("nowhere", "no such folder"),
        ("empty", "no summary.json"),
        ("odd", "no 'status' field"),
    ):
        result = sil("compare", str(tmp_path / folder), str(tmp_path / folder))
        assert result.returncode == 2 and why in result.stderr, result.stderr
        assert str(tmp_path / folder) in result.stderr


def test_a_summary_with_nan_metrics_is_strict_json(tmp_path, monkeypatch):
    from protocol import strict_json
    from sil.analysis import metrics
    from sil.cli import main

    summarize = metrics.summarize

    def with_non_finite(*args, **kwargs):
        return {**summarize(*args, **kwargs), "tracking_rms_pct": math.nan, "extra": -math.inf}

    monkeypatch.setattr(metrics, "summarize", with_non_finite)
    out = tmp_path / "run"
    argv = ["run", str(_scenario(tmp_path, "nan", 1.0)), "--mode", "inproc", "--no-plots"]
    assert main([*argv, "--out", str(out)]) == 0
    summary = strict_json.loads((out / "summary.json").read_text())  # NaN would raise
    assert summary["tracking_rms_pct"] is None and summary["extra"] is None
    results.write_summary(tmp_path, {"status": "completed", "x": math.nan})
    assert strict_json.loads((tmp_path / "summary.json").read_text())["x"] is None
