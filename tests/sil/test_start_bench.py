"""`sil bench starts`: its quick scenario files, and its verdict on starts alike in every mode
(the bench itself, minutes long, runs in `sil bench all`)."""

from __future__ import annotations

from sil import scenario as scenarios
from sil.bench import starts as bench


def _figures(**changed) -> dict:
    """Every start alike in process, lockstep and real time, with ``changed`` keys."""
    figures = {}
    for name in bench.SCENARIOS:
        key = bench._key(name)
        for suffix in ("", "_lockstep", "_realtime"):
            if name == "start-no-light":
                figures[f"{key}_start_abort{suffix}"] = "IGNITION_TIMEOUT"
            else:
                figures[f"{key}_start_time_s{suffix}"] = 21.0
            figures[f"{key}_start_egt_peak_K{suffix}"] = 766.0
    return {**figures, **changed}


def test_quick_runs_are_the_start_scenarios_cut_past_their_start(tmp_path):
    for name in bench.SCENARIOS:
        s = scenarios.load(bench._scenario_file(name, tmp_path, quick=True))
        full = scenarios.load(name)
        assert s.duration_s == bench.QUICK_CUT_S[name] < full.duration_s
        assert s.stop_s is None and (s.plant, s.faults) == (full.plant, full.faults)
        assert bench._scenario_file(name, tmp_path, quick=False) == full.path


def test_every_mode_must_start_as_in_process():
    assert bench._same_start(_figures())
    assert bench._same_start(_figures(nominal_start_time_s_realtime=21.9))
    assert not bench._same_start(_figures(nominal_start_time_s_realtime=22.1))
    assert not bench._same_start(_figures(hot_day_start_egt_peak_K_lockstep=797.0))
    assert not bench._same_start(_figures(no_light_start_abort_realtime=None))
    assert not bench._same_start(_figures(cold_day_start_time_s_realtime=None))
