"""`sil bench campaign --quick`: the bus-fault campaign flown with the C ECU on the local pool and
on Dask, its runs a minute on each and the target they are judged against."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from sil.bench import campaign as campaign_bench
from sil.campaign.spec import load


@pytest.mark.slow
def test_quick_bench_flies_one_seed_on_both_executors_and_reports_each_rate() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "sil.cli", "bench", "campaign", "--quick", "--json"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-500:]
    figures = json.loads(proc.stdout)
    shipped = load(campaign_bench.CAMPAIGN)
    assert figures["runs"] == sum(c.values["seed"] == 1 for c in shipped.cases)
    assert figures["same_results_local_and_dask"] is True
    for executor in ("local", "dask"):
        rate = figures[f"runs_per_min_{executor}"]
        assert math.isfinite(rate) and rate > 0
        assert figures[f"runs_per_min_{executor}_runs"] == [rate]
        assert figures["targets_met"][f"runs_per_min_{executor}"] == (rate >= 1000.0)
        assert "1,000 runs a minute" in campaign_bench.TARGET_TEXT[f"runs_per_min_{executor}"]
