"""`sil bench ecu`: microseconds per firmware tick and allocated blocks per 1000 ticks.

The ECU runs the default preset (MRAC, robustness and limiters on: the longest path) in RUN on
a scripted, realistic input sequence (speed swinging around trim with sensor noise, square-wave
demand, EGT near its limit so the limit loop switches in and out, an occasional lost frame),
generated before timing so only the tick is measured. ``tick_build`` says which tick ran: the
compiled one (ecu.compiled_tick) when built from these sources, else the interpreted one.

With ``against`` (``sil bench ecu --against REV``) the tick of the firmware at git revision REV
runs in the same process beside this one: both first replay the same inputs and must give the
same outputs every tick and the same state, then they are timed in alternating rounds (ABBA),
so both see the same load; us_per_tick is then this firmware's from those rounds (CPU time of
the process, which another process's load on the machine disturbs far less than the wall
clock), us_per_tick_against REV's, and speedup the median of the rounds' ratios (REV's time over
this one's).
"""

from __future__ import annotations

import gc
import importlib
import io
import shutil
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from array import array
from pathlib import Path
from types import ModuleType

from ecu import compiled_tick
from ecu.firmware import Ecu, EcuInputs

RPM_PER_PCT = 1125


def scripted_inputs(n: int, rate_hz: int = 100) -> tuple[array, array, array, array]:
    """Speed (rpm), EGT (0.1 K), demand (0.01 %N) and sensor-frame status per tick."""
    speed = array("i", [0] * n)
    egt = array("i", [0] * n)
    demand = array("i", [0] * n)
    status = array("i", [0] * n)
    seed = 12345
    n_pct = 89.68
    warm = 40 * rate_hz  # two periods first, so the sequence repeats without a jump
    for kk in range(warm + n):
        k = kk - warm
        t = kk / rate_hz
        up = (t % 20.0) < 10.0
        target = 92.0 if up else 87.5
        n_pct += (target - n_pct) * (1.5 / rate_hz)
        seed = (1103515245 * seed + 12345) & 0x7FFFFFFF
        noise = (seed % 7) - 3  # +-3 rpm
        if k < 0:
            continue
        speed[k] = round(n_pct * RPM_PER_PCT) + noise
        egt[k] = 10480 + round((n_pct - 89.68) * 200) + ((seed >> 8) % 5)
        demand[k] = 9200 if up else 8750
        status[k] = 4 if k % 997 == 500 else 0  # one lost sensor frame now and then
    return speed, egt, demand, status


def _drive(
    ecu: Ecu, i: EcuInputs, inputs: tuple[array, array, array, array], k0: int, n: int
) -> None:
    speed, egt, demand, status = inputs
    size = len(speed)
    for k in range(k0, k0 + n):
        j = k % size
        i.tick = k
        i.speed_rpm = speed[j]
        i.egt_dk = egt[j]
        i.demand_cpct = demand[j]
        i.sensor_status = status[j]
        ecu.tick(i)


def new_running_ecu() -> tuple[Ecu, EcuInputs]:
    """A default-preset ECU armed with plausible inputs (it enters RUN on the first ticks)."""
    ecu = Ecu()
    i = EcuInputs()
    i.speed_rpm = 100890
    i.egt_dk = 10480
    i.supply_mv = 22200
    i.pump_ma = 1800
    i.demand_cpct = 8968
    i.arm = 1
    return ecu, i


TARGET_TEXT = {
    "no_allocation_per_tick": "under 1 allocated block per 1,000 firmware ticks",
    "compiled_speedup": ">= 1.5x: the compiled tick against the interpreted one of the same "
    "source, side by side, the same outputs and state",
}
COMPILED_SPEEDUP = 1.5


def run(quick: bool = False, against: str | None = None) -> dict:
    other = firmware_at(against) if against is not None else None
    n = 5_000 if quick else 50_000
    inputs = scripted_inputs(20_000)
    ecu, i = new_running_ecu()
    _drive(ecu, i, inputs, 0, 2_000)  # warm-up
    gc.collect()
    blocks0 = sys.getallocatedblocks()
    t0 = time.perf_counter()
    _drive(ecu, i, inputs, 2_000, n)
    elapsed = time.perf_counter() - t0
    gc.collect()
    blocks1 = sys.getallocatedblocks()
    per_1k = (blocks1 - blocks0) * 1000 / n
    figures = {
        "us_per_tick": round(elapsed / n * 1e6, 2),
        "alloc_blocks_per_1k_ticks": round(per_1k, 3),
        "ticks": n,
        "mode_at_end": ecu.out.mode,
        "tick_build": "compiled" if compiled_tick.in_use() else "interpreted",
        "sat_events": ecu.out.sat_events,
        "targets_met": {"no_allocation_per_tick": per_1k < 1},
    }
    if compiled_tick.in_use():
        side = compare_with(interpreted_firmware(), inputs, n)
        figures["us_per_tick_interpreted"] = side["us_per_tick_against"]
        figures["compiled_speedup"] = side["speedup"]
        figures["compiled_same_outputs_and_state"] = side["same_outputs_and_state"]
        figures["targets_met"]["compiled_speedup"] = (
            side["speedup"] >= COMPILED_SPEEDUP and side["same_outputs_and_state"]
        )
    else:
        figures["targets_met"]["compiled_speedup"] = False  # (no build: no C compiler here)
    if other is not None:
        figures.update(compare_with(other, inputs, n))
        figures["against"] = against
    return figures


def firmware_at(rev: str) -> ModuleType:
    """The module ecu.firmware of git revision ``rev``, imported beside this process's own ecu
    package (its modules under their own names while it loads, then put aside); ValueError
    for a revision git does not know."""
    if rev.startswith("-"):
        raise ValueError(f"--against {rev}: not a git revision")
    repo = Path(__file__).resolve().parent.parent
    done = subprocess.run(
        ["git", "archive", "--format=tar", rev, "ecu"], cwd=repo, capture_output=True, check=False
    )
    if done.returncode != 0:
        message = done.stderr.decode(errors="replace").strip().splitlines()
        raise ValueError(f"--against {rev}: {message[-1] if message else 'git archive failed'}")
    with tempfile.TemporaryDirectory(prefix="ecu-bench-") as root:
        with tarfile.open(fileobj=io.BytesIO(done.stdout)) as tar:
            tar.extractall(root, filter="data")
        return _import_beside(root)


def interpreted_firmware() -> ModuleType:
    """This package's ecu.firmware interpreted (no compiled build beside its sources),
    imported beside the one this process runs."""
    with tempfile.TemporaryDirectory(prefix="ecu-bench-") as root:
        (Path(root) / "ecu").mkdir()
        for path in compiled_tick.PACKAGE.glob("*.py"):  # (the tick's: no subpackage)
            shutil.copy2(path, Path(root) / "ecu" / path.name)
        return _import_beside(root)


def _import_beside(root: str) -> ModuleType:
    ours = {name: m for name, m in sys.modules.items() if name.split(".")[0] == "ecu"}
    for name in ours:
        del sys.modules[name]
    sys.path.insert(0, root)
    try:
        return importlib.import_module("ecu.firmware")
    finally:
        sys.path.remove(root)
        for name in [name for name in sys.modules if name.split(".")[0] == "ecu"]:
            del sys.modules[name]
        sys.modules.update(ours)


def _same(a: object, b: object) -> bool:
    """Two records (outputs or state) hold the same values, slot by slot."""
    for name in type(a).FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        if (list(x) if isinstance(x, array) else x) != (list(y) if isinstance(y, array) else y):
            return False
    return True


def compare_with(other: ModuleType, inputs: tuple, n: int, rounds: int = 20) -> dict:
    """This firmware's tick and ``other``'s (an ecu.firmware module) on the same inputs: the
    same outputs every tick and the same state at the end (replayed untimed first), then
    microseconds per tick of each (CPU time), timed in alternating rounds of n / rounds ticks."""
    ours, i = new_running_ecu()
    theirs = other.Ecu()
    j = other.EcuInputs()
    for name in EcuInputs.FIELDS:
        setattr(j, name, getattr(i, name))
    same = True
    for k in range(2_000):
        _drive(ours, i, inputs, k, 1)
        _drive(theirs, j, inputs, k, 1)
        same = same and _same(ours.out, theirs.out)
    same = same and _same(ours.s, theirs.s)
    chunk = max(1, n // rounds)
    k0 = 2_000
    spent = {"ours": 0.0, "theirs": 0.0}
    ratios = []
    for r in range(rounds):
        took = {}
        order = (("ours", ours, i), ("theirs", theirs, j))
        for who, e, e_in in order if r % 2 == 0 else order[::-1]:
            t0 = time.process_time()
            _drive(e, e_in, inputs, k0, chunk)
            took[who] = time.process_time() - t0
            spent[who] += took[who]
        ratios.append(took["theirs"] / max(took["ours"], 1e-9))
        k0 += chunk
    return {
        "us_per_tick": round(spent["ours"] / (chunk * rounds) * 1e6, 2),
        "us_per_tick_against": round(spent["theirs"] / (chunk * rounds) * 1e6, 2),
        "speedup": round(statistics.median(ratios), 3),
        "same_outputs_and_state": same and _same(ours.s, theirs.s),
    }
