"""Run a campaign's cases on a local process pool or a Dask cluster, in batches of consecutive
cases (:func:`batches`); results stream into one CSV table (``results.csv``) as batches finish,
so an interrupted campaign resumes where it stopped.

A case that raises is recorded as failed with its error and the campaign goes on. A case counts
as done when the table has a completed row with its run ID, content digest and ECU
implementation: a resumed
campaign reruns failed cases and the cases a changed campaign file changed (the report reads
the last row of each run).
"""

from __future__ import annotations

import csv
import math
import os
import signal
import sys
import time
import traceback
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

from protocol import strict_json
from sil.campaign.spec import Campaign, Case, Invariants
from sil.run.parent_death import die_with_parent

FIGURES = (
    "ticks", "wall_s", "tracking_rms_pct", "tracking_speed_loop_rms_pct", "tracking_mean_pct",
    "max_n_pct", "max_egt_K", "max_egt_time_s", "egt_limit_time_s", "protection_time_s",
    "pump_v_min", "pump_v_max", "final_mode", "fault_bits",
    "stalls", "step_pct", "thrust_rise_s", "egt_overshoot_K", "min_surge_margin_pct",
    "flameouts", "min_speed_pct",
    "start_time_s", "start_egt_peak_K", "start_abort", "unburnt_fuel_kg", "cool_down_s",
)  # fmt: skip


BATCHES_PER_WORKER = 8
BATCH_MAX = 16


@dataclass(frozen=True)
class Task:
    run_id: str
    scenario_toml: str
    base_dir: str
    invariants: Invariants
    ecu_impl: str = "python"


def run_task(task: Task) -> dict:
    """One case in a worker: its row of the table (never raises)."""
    from sil import scenario as scenarios
    from sil.campaign.case import run_case
    from sil.campaign.invariants import check

    row: dict = {"run_id": task.run_id, "ecu_impl": task.ecu_impl}
    try:
        s = scenarios.parse(task.scenario_toml, task.run_id, Path(task.base_dir))
        fig, detections, violations = check(run_case(s, ecu_impl=task.ecu_impl), task.invariants)
        row.update(fig, status="completed", error="", detections=strict_json.dumps(detections))
        row.update(violations="; ".join(violations), n_violations=len(violations))
    except Exception as exc:  # a crashing run is recorded, the campaign goes on
        where = traceback.extract_tb(exc.__traceback__)[-1]
        row.update(status="failed", error=f"{type(exc).__name__}: {exc} ({where.filename}:"
                   f"{where.lineno})")  # fmt: skip
    return row


def run_batch(tasks: list[Task]) -> list[dict]:
    """Several cases in a worker, one after another: their rows (the executor's cost per task
    is paid once for the batch)."""
    return [run_task(t) for t in tasks]


def batches(tasks: list[Task], workers: int) -> list[list[Task]]:
    """The tasks in batches of consecutive cases: about BATCHES_PER_WORKER per worker, so the
    workers stay evenly loaded to the end, and at most BATCH_MAX cases, so rows keep coming."""
    size = max(1, min(BATCH_MAX, len(tasks) // (workers * BATCHES_PER_WORKER)))
    return [tasks[i : i + size] for i in range(0, len(tasks), size)]


def columns(campaign: Campaign) -> list[str]:
    return [
        "run_id", "digest", "ecu_impl", "sample", *campaign.axes, "status", "error", *FIGURES,
        "n_violations", "violations", "detections",
    ]  # fmt: skip


class Table:
    """results.csv: read what is done, append rows as they come (flushed each time)."""

    def __init__(self, path: Path, campaign: Campaign) -> None:
        self.path = path
        self.fields = columns(campaign)
        self.done: set[tuple[str, str, str]] = set()
        if path.exists() and path.stat().st_size:
            with path.open(newline="") as f:
                reader = csv.DictReader(f)
                if reader.fieldnames != self.fields:
                    raise ValueError(
                        f"{path}: written by another campaign layout (columns differ); "
                        "use another --out or remove it"
                    )
                self.done = {
                    (r["run_id"], r["digest"], r["ecu_impl"])
                    for r in reader
                    if r["status"] == "completed"
                }
            self._file = path.open("a", newline="")
            self._writer = csv.DictWriter(self._file, self.fields)
        else:
            self._file = path.open("w", newline="")
            self._writer = csv.DictWriter(self._file, self.fields)
            self._writer.writeheader()

    def add(self, case: Case, row: dict) -> None:
        out = {"digest": case.digest, "sample": case.sample, **case.values, **row}
        self._writer.writerow({k: _cell(out.get(k, "")) for k in self.fields})
        self._file.flush()

    def close(self) -> None:
        self._file.close()


def _cell(v: object) -> object:
    if isinstance(v, float) and math.isnan(v):
        return ""
    return v


def _worker_init() -> None:
    """Workers die with the campaign (Linux), leave Ctrl-C to it, and end quietly when it stops
    them (not with the campaign's own SIGTERM handler, inherited through fork)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    die_with_parent()


def _local(tasks: list[Task], workers: int) -> Iterator[dict]:
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_worker_init)
    try:
        futures = [pool.submit(run_batch, batch) for batch in batches(tasks, workers)]
        for future in as_completed(futures):
            yield from future.result()
    finally:  # interrupted: drop what has not started, stop the workers now
        running = list((pool._processes or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in running:
            proc.terminate()


def _dask(tasks: list[Task], workers: int, scheduler: str | None) -> Iterator[dict]:
    from dask.distributed import Client, LocalCluster
    from dask.distributed import as_completed as dask_completed

    cluster = None
    if scheduler is None:
        cluster = LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
        )
        client = Client(cluster)
    else:
        client = Client(scheduler)
    try:
        threads = sum(client.nthreads().values()) or workers  # (the cluster's, when remote)
        futures = client.map(run_batch, batches(tasks, threads), pure=False)
        for _, rows in dask_completed(futures, with_results=True):
            yield from rows
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


@dataclass
class Outcome:
    total: int
    skipped: int
    completed: int
    failed: int
    violations: int
    wall_s: float

    @property
    def runs_per_min(self) -> float:
        ran = self.completed + self.failed
        return 60.0 * ran / self.wall_s if self.wall_s > 0 and ran else math.nan


def execute(
    campaign: Campaign,
    out: Path,
    *,
    executor: str = "local",
    ecu_impl: str = "python",
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
) -> Outcome:
    """Run the cases not yet in ``out/results.csv``; write each case's scenario file."""
    from tqdm import tqdm

    scen_dir = out / "scenarios"
    scen_dir.mkdir(parents=True, exist_ok=True)
    for case in campaign.cases:
        (scen_dir / f"{case.run_id}.toml").write_text(case.scenario_toml)
    table = Table(out / "results.csv", campaign)
    todo = [c for c in campaign.cases if (c.run_id, c.digest, ecu_impl) not in table.done]
    by_id = {c.run_id: c for c in todo}
    base_dir = str(campaign.path.parent.resolve())
    tasks = [Task(c.run_id, c.scenario_toml, base_dir, campaign.invariants, ecu_impl) for c in todo]
    workers = workers or os.cpu_count() or 1
    outcome = Outcome(len(campaign.cases), len(campaign.cases) - len(todo), 0, 0, 0, 0.0)
    bar = tqdm(total=len(todo), desc=campaign.name, unit="run", disable=not progress,
               file=sys.stderr, smoothing=0.05)  # fmt: skip
    t0 = time.perf_counter()
    try:
        rows = _dask(tasks, workers, scheduler) if executor == "dask" else _local(tasks, workers)
        for row in rows:
            table.add(by_id[row["run_id"]], row)
            if row["status"] == "failed":
                outcome.failed += 1
            else:
                outcome.completed += 1
                outcome.violations += row["n_violations"] > 0
            bar.set_postfix(failed=outcome.failed, violating=outcome.violations, refresh=False)
            bar.update()
    finally:
        outcome.wall_s = time.perf_counter() - t0
        bar.close()
        table.close()
    return outcome
