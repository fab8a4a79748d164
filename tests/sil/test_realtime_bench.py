"""`sil bench realtime`: each node's period-start lateness and overruns at 100 Hz and 1 kHz, from
real-time runs as a user makes them."""

from sil import realtime_bench


def test_realtime_bench_reports_each_node_at_each_rate(monkeypatch):
    monkeypatch.setattr(realtime_bench, "QUICK_S", 2.0)
    figures = realtime_bench.run(quick=True)
    assert figures["seconds_per_case"] == 2.0
    for rate in realtime_bench.RATES_HZ:
        assert figures[f"missed_ticks_{rate}hz"] == 0
        for node in realtime_bench.NODES:
            key = f"{node}_{rate}hz"
            p50, p99, top = (figures[f"{key}_lateness_{q}_ms"] for q in ("p50", "p99", "max"))
            assert 0.0 <= p50 <= p99 <= top
            assert figures[f"{key}_scheduling"] in ("normal", "SCHED_FIFO 10")
            # both nodes keep the ECU's period (the plant steps 1 ms at a time within it)
            periods = figures[f"{key}_periods"]
            expected = 2.0 * rate
            assert 0.9 * expected <= periods + figures[f"{key}_overruns"] <= 1.2 * expected
    assert isinstance(figures["targets_met"], bool)
