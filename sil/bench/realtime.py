"""`sil bench realtime`: how well the nodes keep their periods in real time, at 100 Hz and 1 kHz.

Each case is ``sil run SCENARIO --mode realtime`` in a process of its own, as a user runs it: the
plant and the ECU as separate processes on the run's loopback bus, both at the case's ECU rate
(the plant steps its 1 ms steps within a period), the recorder writing beside them. From each
node's summary: the lateness of its period starts against their absolute deadlines (p50, p99,
max), its overruns (periods started more than a period late) and the scheduling it had. The
machine's load before the runs is given, and, on a virtual machine, the CPU time its hypervisor
took from it during each case (steal time, /proc/stat): the figures are of the machine as it was,
and a host that stalls the machine shows as overruns no node could prevent.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from sil.bench.common import BenchError, finished_run, scenario_cut

SCENARIO = "thesis-5.4-staircase"
RATES_HZ = (100, 1000)
DURATION_S = 30.0
QUICK_S = 10.0
TARGETS_MS = {"p50": 0.05, "p99": 0.3}  # period-start lateness, at most; and no overrun
NODES = ("plant", "ecu")
TARGET_TEXT = {
    "targets": f"period-start lateness p50 <= {TARGETS_MS['p50']} ms, p99 <= {TARGETS_MS['p99']} "
    "ms, no overrun, each node at 100 Hz and 1 kHz, each run completed"
}


PROC_STAT = Path("/proc/stat")


def steal_s(stat: Path = PROC_STAT) -> float | None:
    """CPU time the hypervisor has taken from this machine's CPUs since boot (the steal column of
    /proc/stat's cpu line, in clock ticks), in seconds; None where the kernel does not tell."""
    try:
        fields = stat.read_text().splitlines()[0].split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def run(quick: bool = False) -> dict:
    seconds = QUICK_S if quick else DURATION_S
    figures: dict = {
        "scenario": SCENARIO,
        "seconds_per_case": seconds,
        "cpus": os.cpu_count(),
        "load_average_1min_before": round(os.getloadavg()[0], 2),
    }
    met = True
    with tempfile.TemporaryDirectory() as tmp:
        for rate in RATES_HZ:
            path = scenario_cut(SCENARIO, seconds, Path(tmp), head=f"ecu_rate_hz = {rate}\n")
            # a run that lost ticks to overruns ends early (aborted): its figures still count
            stolen = steal_s()
            summary = finished_run(path, Path(tmp) / f"out-{rate}", "--mode", "realtime")
            if stolen is not None:
                figures[f"host_steal_{rate}hz_ms"] = round(1000.0 * (steal_s() - stolen), 1)
            status = summary.get("status")
            figures[f"status_{rate}hz"] = (
                status if status == "completed" else f"{status}: {summary.get('abort_reason')}"
            )
            met = met and status == "completed"
            figures[f"missed_ticks_{rate}hz"] = summary.get("missed_ticks")
            for node in NODES:
                stats = summary.get("nodes", {}).get(node, {})
                late = stats.get("jitter_ms")
                if late is None:
                    raise BenchError(f"{rate} Hz: the {node} node reported no period lateness")
                key = f"{node}_{rate}hz"
                for q in ("p50", "p99", "max"):
                    figures[f"{key}_lateness_{q}_ms"] = round(late[q], 4)
                figures[f"{key}_periods"] = stats.get("periods")
                figures[f"{key}_overruns"] = stats.get("overruns")
                figures[f"{key}_scheduling"] = stats.get("scheduling")
                met = met and all(late[q] <= TARGETS_MS[q] for q in TARGETS_MS)
                met = met and stats.get("overruns") == 0
    figures["targets"] = (
        f"period-start lateness p50 <= {TARGETS_MS['p50']} ms, p99 <= {TARGETS_MS['p99']} ms, "
        "no overrun, each node at each rate, each run completed"
    )
    figures["targets_met"] = met
    return figures
