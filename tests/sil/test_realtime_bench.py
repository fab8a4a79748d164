"""`sil bench realtime`: each node's period-start lateness and overruns at 100 Hz and 1 kHz, from
real-time runs as a user makes them."""

import os

from sil.bench import realtime as realtime_bench


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
        if realtime_bench.steal_s() is not None:  # Linux: what a hypervisor took, never negative
            assert 0.0 <= figures[f"host_steal_{rate}hz_ms"] < 2000.0 * 2 * figures["cpus"]
    assert isinstance(figures["targets_met"], bool)


def test_steal_time_is_read_from_the_cpu_line(tmp_path):
    stat = tmp_path / "stat"
    stat.write_text("cpu  10 0 5 900 2 0 1 250 0 0\ncpu0 5 0 2 450 1 0 0 125 0 0\n")
    assert realtime_bench.steal_s(stat) == 250 / os.sysconf("SC_CLK_TCK")
    stat.write_text("cpu  10 0 5\n")  # a kernel without the column
    assert realtime_bench.steal_s(stat) is None
    assert realtime_bench.steal_s(tmp_path / "none") is None
