"""`sil steady-line` and `sil bench plant`."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from sil.cli import main


def test_running_line_is_monotone_and_passes_the_trim(running, reference):
    n, fuel = running["N_pct"], running["fuel_kg_s"]
    assert np.all(np.diff(n) > 0) and np.all(np.diff(fuel) > 0)
    for key in ("P3_Pa", "thrust_N", "air_kg_s"):
        assert np.all(np.diff(running[key]) > 0), key
    i = int(np.argmin(np.abs(fuel - 0.008)))
    assert n[i] == pytest.approx(reference["trim_point_eq_2_32"]["N_pct"], abs=0.5)
    assert n[0] < 45.0 and n[-1] > 100.0  # idle to above the rated speed


def test_running_line_at_rated_speed_is_an_olympus_class_engine(running, reference):
    spec = reference["engine_spec_amt_olympus"]
    at = {k: float(np.interp(100.0, running["N_pct"], running[k])) for k in running}
    assert at["thrust_N"] == pytest.approx(spec["max_thrust_N"], rel=0.25)
    assert at["P3_Pa"] / 101325.0 == pytest.approx(spec["pressure_ratio"], rel=0.15)
    assert at["air_kg_s"] == pytest.approx(spec["mass_flow_kg_s"], rel=0.25)


def test_sil_steady_line_writes_csv_and_png(tmp_path, capsys, running):
    assert main(["steady-line", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "steady_line.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(running["N_pct"])
    assert float(rows[0]["N_pct"]) == pytest.approx(running["N_pct"][0], rel=1e-8)
    assert (tmp_path / "staircase.png").read_bytes()[:4] == b"\x89PNG"
    png = (tmp_path / "steady_line.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_sil_bench_plant_reports_both_plants(capsys):
    assert main(["bench", "plant", "--quick", "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    for key in (
        "realtime_factor",
        "step_api_realtime_factor",
        "fast_realtime_factor",
        "fast_step_api_realtime_factor",
    ):
        assert figures[key] > 1.0, key
    assert figures["fast_realtime_factor"] > figures["realtime_factor"]
