"""`sil bench pil`: the firmware image on the emulated Cortex-M4 in the loop.

One ``sil run SCENARIO --ecu-impl pil`` in lockstep on each of the image's CAN links (Ethernet,
the default, and slcan on its UART), as a user runs it, beside the same run with the host C ECU
(``--ecu-impl c``): whether the can.log files are byte-identical, the speed of each against real
time, the image's instructions per tick measured in the loop (core and whole
node call, mean and max) against the golden-vector figure of the same core under QEMU, the CPU
load at 100 Hz and 1 kHz on a 168 MHz Cortex-M4 at one instruction per cycle, and the image's
flash and RAM.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

from ecu.port.build import ARM_CC, ARM_CC_NOT_FOUND
from ecu.port.qemu import QEMU, QEMU_NOT_FOUND
from sil.bench.common import BenchError, completed_run, scenario_cut

SCENARIO = "thesis-5.2-mrac-fast"
DURATION_S = 60.0
QUICK_S = 15.0
TARGET_REALTIME_FACTOR = 10.0
TARGET_INSTRUCTIONS_RATIO = 0.05  # in the loop against the golden vectors, at most
TARGET_TEXT = {
    "identical": "can.log byte-identical to the C ECU's, on both links",
    "realtime_factor_10x": ">= 10x real time in lockstep (Ethernet link)",
    "instructions_within_5pct": "instructions per tick in the loop within 5 % of the golden "
    "vectors'",
}


def run(quick: bool = False) -> dict:
    from ecu import golden
    from sil.bench import port as port_bench
    from sil.run import golden as sources

    tools = ((ARM_CC, ARM_CC_NOT_FOUND), (QEMU, QEMU_NOT_FOUND))
    missing = [text for tool, text in tools if shutil.which(tool) is None]
    if missing:  # before any run: each would fail on it
        raise BenchError("; ".join(missing))
    seconds = QUICK_S if quick else DURATION_S
    with tempfile.TemporaryDirectory() as tmp:
        path = scenario_cut(SCENARIO, seconds, Path(tmp))
        pil = completed_run(path, Path(tmp) / "pil", "--ecu-impl", "pil")
        slcan = completed_run(path, Path(tmp) / "slcan", "--ecu-impl", "pil", "--pil-link", "slcan")
        c = completed_run(path, Path(tmp) / "c", "--ecu-impl", "c")
        c_log = (Path(tmp) / "c" / "can.log").read_bytes()
        identical = (Path(tmp) / "pil" / "can.log").read_bytes() == c_log
        slcan_identical = (Path(tmp) / "slcan" / "can.log").read_bytes() == c_log
        vectors = Path(tmp) / "pil-scenario.gv"
        g = sources.record_scenario("pil-scenario", SCENARIO, round(seconds * 100))
        golden.write(g, vectors)
        golden_instructions = port_bench.qemu_instructions(vectors, g.ticks)
    figures = pil.get("pil", {})
    per_tick = figures.get("instructions_per_tick", {})
    core = per_tick.get("core_mean")
    ratio = core / golden_instructions - 1.0 if isinstance(golden_instructions, float) else None
    out = {
        "scenario": f"{SCENARIO} ({seconds:g} s, lockstep)",
        "can_log_identical_to_c": identical,
        "slcan_can_log_identical_to_c": slcan_identical,
        "pil_realtime_factor": round(pil["realtime_factor"], 2),
        "pil_slcan_realtime_factor": round(slcan["realtime_factor"], 2),
        "c_realtime_factor": round(c["realtime_factor"], 2),
        "pil_startup_s": round(pil.get("startup_s", float("nan")), 2),
        "ticks_profiled": figures.get("ticks_profiled"),
        **{f"instructions_{k}": v for k, v in per_tick.items()},
        "golden_vector_instructions": golden_instructions,
        "core_vs_golden_pct": None if ratio is None else round(100 * ratio, 2),
        **{
            f"cpu_load_{k}_pct": v
            for k, v in figures.get("cpu_load_pct", {}).items()
            if k != "assumes"
        },  # fmt: skip
        "cpu_load_assumes": figures.get("cpu_load_pct", {}).get("assumes"),
        **figures.get("image", {}),
        "watchdog_resets": figures.get("watchdog_resets"),
    }
    out["targets_met"] = {
        "identical": identical and slcan_identical,
        "realtime_factor_10x": out["pil_realtime_factor"] >= TARGET_REALTIME_FACTOR,
        "instructions_within_5pct": ratio is not None and abs(ratio) <= TARGET_INSTRUCTIONS_RATIO,
    }
    return out
