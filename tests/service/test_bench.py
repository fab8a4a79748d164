"""`sil bench service --quick`: the figures come out and are plausible."""

import json
import subprocess
import sys


def test_bench_service_quick():
    done = subprocess.run(
        [sys.executable, "-m", "sil.cli", "bench", "service", "--quick", "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    figures = json.loads(done.stdout)
    assert figures["pty_link_frames_per_s"] > 1000 and figures["live_frame_bytes"] > 60
    assert figures["pty_stream_frames_per_s"] > 1000
    assert figures["pty_request_round_trips_per_s"] > 50
    assert figures["budget_stream_samples_lost"] == 0 and figures["budget_client_cycles"] > 0
    assert 0 < figures["service_mean_us_per_tick"] <= figures["service_worst_us_per_tick"]
    assert 0 < figures["service_worst_cpu_us_per_tick"] < 10_000  # CPU inside a 10 ms tick
    assert figures["service_polls_that_blocked"] < figures["budget_ticks"]
