"""Campaigns end to end: local pool and Dask agree run for run, resume, failures, invariants,
bus fault detection, and the printed `sil run` line reproduces a run."""

import csv
import json
import shlex
from pathlib import Path

import pytest

from sil.campaign.executors import Task, columns, execute, run_task
from sil.campaign.report import load as load_rows
from sil.campaign.spec import Invariants, load
from sil.cli import main
from tests.campaign.conftest import BUS, NOMINAL, SMALL


def rows(out: Path) -> dict[str, dict]:
    with (out / "results.csv").open(newline="") as f:
        return {r["run_id"]: r for r in csv.DictReader(f)}


def without_wall(r: dict) -> dict:
    return {k: v for k, v in r.items() if k != "wall_s"}


@pytest.mark.slow
def test_local_and_dask_give_identical_runs_and_a_resumed_campaign_skips_them(write, tmp_path):
    path = write(SMALL)
    local, dask = tmp_path / "local", tmp_path / "dask"
    assert (
        main(["campaign", str(path), "--out", str(local), "--workers", "2", "--no-progress"]) == 0
    )
    argv = ["campaign", str(path), "--out", str(dask), "--executor", "dask", "--workers", "2"]
    assert main([*argv, "--no-progress"]) == 0
    a, b = rows(local), rows(dask)
    assert len(a) == 6 and all(r["status"] == "completed" for r in a.values())
    assert {k: without_wall(r) for k, r in a.items()} == {k: without_wall(r) for k, r in b.items()}
    # resumed: nothing runs again, nothing is appended
    outcome = execute(load(path), local, workers=2, progress=False)
    assert (outcome.skipped, outcome.completed) == (6, 0)
    assert len((local / "results.csv").read_text().splitlines()) == 7
    report = (local / "report.md").read_text()
    assert "| mrac | 2 |" in report and "| pid | 2 |" in report
    assert (local / "tracking_rms.png").stat().st_size > 0


def test_a_crashing_run_is_recorded_failed_and_rerun_on_resume(write, tmp_path):
    row = run_task(Task("00000", "duration_s = -1\n[command]\n", ".", Invariants()))
    assert row["status"] == "failed" and "duration_s" in row["error"]
    campaign = load(write(NOMINAL))
    out = tmp_path / "out"
    out.mkdir()
    # a table where the first case failed: a resumed campaign runs it again
    with (out / "results.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, columns(campaign))
        w.writeheader()
        case = campaign.cases[0]
        w.writerow({"run_id": case.run_id, "digest": case.digest, "status": "failed"})
    outcome = execute(campaign, out, workers=1, progress=False)
    assert (outcome.skipped, outcome.completed) == (0, 2)
    assert [r["status"] for r in load_rows(out / "results.csv")] == ["completed", "completed"]


@pytest.mark.slow
def test_violations_are_reported_with_a_sil_run_line_that_reproduces_the_run(write, tmp_path):
    text = NOMINAL + "\n[invariants]\nmax_speed_pct = 89.0\n"
    out = tmp_path / "out"
    assert main(["campaign", str(write(text)), "--out", str(out), "--no-progress"]) == 1
    report = (out / "report.md").read_text()
    lines = [ln.strip().strip("`") for ln in report.splitlines() if "sil run " in ln]
    assert len(lines) == 2 and "overspeed" in report
    r = rows(out)["00000"]
    assert r["n_violations"] == "1" and r["violations"].startswith("overspeed: ")
    argv = shlex.split(lines[0])[1:]
    assert argv[:2] == ["run", str(out / "scenarios" / "00000.toml")]
    assert main([*argv, "--no-plots"]) == 0
    summary = json.loads((out / "repro" / "00000" / "summary.json").read_text())
    assert summary["tracking_rms_pct"] == pytest.approx(float(r["tracking_rms_pct"]), rel=1e-6)


@pytest.mark.slow
def test_bus_fault_campaign_detects_what_it_must(write, tmp_path):
    out = tmp_path / "out"
    assert main(["campaign", str(write(BUS)), "--out", str(out), "--no-progress"]) == 0
    by_variant = {r["variant"]: r for r in rows(out).values()}
    flips = json.loads(by_variant["flips"]["detections"])[0]
    assert flips["detected"] and flips["missed"] == 0 and flips["caught"] > 10
    loss = json.loads(by_variant["loss"]["detections"])[0]
    assert loss["detected"] and loss["fallback"] and loss["detect_ticks"] <= 5
    assert by_variant["loss"]["final_mode"] == "FAULT"
    short = json.loads(by_variant["short-loss"]["detections"])[0]
    assert short["detected"] and short["recovered"]
    assert by_variant["short-loss"]["final_mode"] == "RUN"
    assert "| flips (bitflip, E2E) | 1 | 1/1 (100 %) |" in (out / "report.md").read_text()


def test_the_c_ecu_gives_the_same_runs_as_the_python_one(write, tmp_path):
    campaign = load(write(NOMINAL))
    python = execute(campaign, tmp_path / "py", workers=2, progress=False)
    c = execute(campaign, tmp_path / "c", ecu_impl="c", workers=2, progress=False)
    assert python.completed == c.completed == 2
    a, b = rows(tmp_path / "py"), rows(tmp_path / "c")
    drop = ("wall_s", "ecu_impl")
    assert {i: {k: v for k, v in r.items() if k not in drop} for i, r in a.items()} == {
        i: {k: v for k, v in r.items() if k not in drop} for i, r in b.items()
    }


@pytest.mark.slow
def test_an_interrupted_campaign_stops_its_workers_and_resumes(write, tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    path = write(SMALL.replace("samples = 2", "samples = 5"))  # 12 runs
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "sil.cli", "campaign", str(path), "--out", str(out)]
    proc = subprocess.Popen([*argv, "--workers", "2", "--no-progress", "--no-report"])
    table = out / "results.csv"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and (
        not table.exists() or len(table.read_text().splitlines()) < 3
    ):
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(30) == 130
    done = len(rows(out))
    assert 2 <= done < 12
    time.sleep(0.5)
    workers = subprocess.run(["pgrep", "-f", str(out)], capture_output=True, text=True).stdout
    assert workers.split() == [] or workers.split() == [str(os.getpid())]
    outcome = execute(load(path), out, workers=2, progress=False)
    assert outcome.skipped == done and outcome.completed == 12 - done
    assert len(rows(out)) == 12


def test_workers_beyond_four_per_core_are_refused(write, capsys):
    import os

    path = write(SMALL)
    too_many = 4 * (os.cpu_count() or 1) + 1
    assert main(["campaign", str(path), "--workers", str(too_many)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--workers: expected a number in 1.." in err
    assert main(["campaign", str(path), "--workers", "0"]) == 2


def test_dask_executor_without_dask_says_how_to_install_it(write, monkeypatch, capsys):
    monkeypatch.setitem(__import__("sys").modules, "dask", None)  # import dask: ImportError
    monkeypatch.setitem(__import__("sys").modules, "dask.distributed", None)
    assert main(["campaign", str(write(SMALL)), "--executor", "dask"]) == 2
    err = capsys.readouterr().err
    assert "--executor dask needs Dask" in err and "pip install 'turbojet-sil[campaign]'" in err
