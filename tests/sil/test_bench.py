"""`sil bench sil`: the runs' figures, the best of the runs, the loop without the start-up."""

import pytest

from sil.bench import speed as bench


def test_sil_bench_reports_every_run_and_the_loop_without_start_up():
    figures = bench.run(quick=True)
    for key in (
        "realtime_factor",
        "inproc_realtime_factor",
        "realtime_factor_c_ecu",
        "inproc_realtime_factor_c_ecu",
        "inproc_realtime_factor_c_ecu_python_loop",
    ):
        runs = figures[f"{key}_runs"]
        assert len(runs) == 1 and figures[key] == max(runs) > 0
    for suffix in ("", "_c_ecu"):
        assert figures[f"lockstep_missed_ticks{suffix}"] == 0
        startup = figures[f"lockstep_startup_s{suffix}"]
        assert 0 < startup < figures[f"lockstep_wall_s{suffix}"]
        # from tick 0 the same simulated time took the wall time less the start-up (both
        # printed to 0.01 s, so the loop's time is known to within 0.01 s)
        loop_s = figures[f"lockstep_wall_s{suffix}"] - startup
        sim_s = figures["sim_time_s"]
        factor = figures[f"lockstep_loop_realtime_factor{suffix}"]
        assert sim_s / (loop_s + 0.01) - 0.01 <= factor <= sim_s / (loop_s - 0.01) + 0.01
        assert "lockstep_aborted" + suffix not in figures
    assert 0 < figures["bus_load_pct"] < 15
    assert figures["inproc_c_ecu_compiled_over_python_loop"] > 0
    assert set(figures["targets_met"]) == set(bench.TARGETS)
    for when in ("before", "after"):  # the machine's pace, each in a loop of its own
        assert 5 < figures[f"python_tick_us_{when}"] < 500
        assert 2 < figures[f"plant_us_per_ecu_tick_{when}"] < 200


def test_a_run_without_its_summary_is_an_error_that_names_it(tmp_path):
    with pytest.raises(bench.BenchError, match="sil run no-such-scenario --mode inproc"):
        bench._sil_run("no-such-scenario", tmp_path / "out", "inproc", "python")
