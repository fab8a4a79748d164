"""The tick allocates nothing that survives it, and the firmware path never touches a float."""

from __future__ import annotations

import ast
import gc
import os
import subprocess
import sys
import tracemalloc
from array import array
from pathlib import Path
from types import FrameType

import ecu
from ecu.bench import _drive, new_running_ecu, scripted_inputs
from ecu.compiled_tick import PURE_ENV
from ecu.firmware import EcuOutputs
from ecu.firmware_params import compile_params
from ecu.state import EcuState

ECU_DIR = Path(ecu.__file__).resolve().parent


def _modules_run_by_ticks() -> frozenset[str]:
    """The ecu/ modules whose code runs inside ``tick()``, found by running it: each controller
    in RUN on the bench's inputs, and a start from rest through the sequencer (the inlet
    correction, the fuel schedules' tables) to a stop. What only sets up (params, the
    parameter compiler) runs outside the tick and is not counted. Compiled modules make no
    profile events: with the compiled tick in use, the interpreted one is traced, in a process
    of its own."""
    if ecu.COMPILED:
        pure = {**os.environ, PURE_ENV: "1"}
        done = subprocess.run([sys.executable, __file__], env=pure, capture_output=True,
                              text=True, check=True)  # fmt: skip
        return frozenset(done.stdout.split())
    from ecu.firmware import E2E_NONEWDATA, E2E_OK, Ecu, EcuInputs
    from ecu.params import EcuParams

    ecus = []
    for controller in ("mrac", "pid", "pi", "open_loop"):
        e, i = new_running_ecu()
        e.p = compile_params(EcuParams(controller=controller))
        ecus.append((e, i))
    rest = Ecu(EcuParams())
    seen: set[str] = set()

    def tracer(frame: FrameType, event: str, arg: object) -> None:
        if event == "call":
            seen.add(frame.f_code.co_filename)

    inputs = scripted_inputs(400)
    i = EcuInputs()
    sys.setprofile(tracer)
    try:
        for e, ei in ecus:
            _drive(e, ei, inputs, 0, 200)
        for k in range(300):  # at rest, armed: spin-up, ignition; then the stop's cool-down
            i.speed_rpm, i.egt_dk, i.supply_mv = 3_000 + 40 * k, 2_900 + 20 * k, 22_200
            i.demand_cpct, i.arm, i.stop = 3_500, 1, 1 if k > 250 else 0
            i.sensor_status = i.analog_status = E2E_OK
            i.demand_status = E2E_OK if k % 5 == 0 else E2E_NONEWDATA
            rest.tick(i)
    finally:
        sys.setprofile(None)
    return frozenset(
        Path(f).stem for f in seen if Path(f).parent == ECU_DIR and Path(f).suffix == ".py"
    )


# the modules whose code runs inside tick() (not configuration, the node, benches or the float
# twins of ecu/reference)
FIRMWARE_MODULES = tuple(sorted(_modules_run_by_ticks() - {"bench", "firmware_params"}))


def test_the_firmware_path_is_found_by_running_it() -> None:
    """The module list the checks below run over is complete: every stage's module is in it."""
    assert set(FIRMWARE_MODULES) >= {
        "fixedpoint", "estimator", "mrac", "pid", "pi", "fast_model", "limiters",
        "pump_driver", "faults", "modes", "firmware", "start_sequencer", "rate_filter",
        "tables", "inlet",
    }  # fmt: skip


def test_100k_ticks_do_not_grow_allocated_blocks() -> None:
    inputs = scripted_inputs(20_000)
    ecu_, i = new_running_ecu()
    _drive(ecu_, i, inputs, 0, 5_000)  # warm-up: every branch and cache seen once
    assert ecu_.out.mode == 2
    gc.collect()
    blocks0 = sys.getallocatedblocks()
    _drive(ecu_, i, inputs, 5_000, 100_000)
    gc.collect()
    blocks1 = sys.getallocatedblocks()
    assert ecu_.out.mode == 2  # still running at the end: the realistic path was exercised
    # the state holds ~100 ints whose objects change from tick to tick; growth would be >> 100k
    assert blocks1 - blocks0 <= 3, f"allocated blocks grew by {blocks1 - blocks0}"


def test_tracemalloc_sees_no_growth_from_ecu_lines() -> None:
    """tracemalloc (much slower, so 6k ticks): blocks held by ecu/ lines stay bounded."""
    inputs = scripted_inputs(20_000)
    ecu_, i = new_running_ecu()
    _drive(ecu_, i, inputs, 0, 2_000)
    tracemalloc.start()
    counts = []
    ecu_files = [tracemalloc.Filter(True, str(ECU_DIR / "*"))]
    for k in range(3):
        _drive(ecu_, i, inputs, 2_000 + k * 2_000, 2_000)
        gc.collect()
        snap = tracemalloc.take_snapshot().filter_traces(ecu_files)
        counts.append(sum(st.count for st in snap.statistics("filename")))
    tracemalloc.stop()
    # live ints held in state (changing objects) only: bounded, and no trend over the ticks
    assert max(counts) < 200, counts
    assert counts[2] - counts[0] < 50, counts


INTEGER_MATH = frozenset({"isqrt", "gcd", "lcm", "comb", "perm", "factorial"})


def _float_nodes(tree: ast.AST) -> list[str]:
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, float):
            bad.append(f"float literal {node.value!r} at line {node.lineno}")
        elif isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div):
            bad.append(f"true division at line {node.lineno}")
        elif isinstance(node, ast.AugAssign) and isinstance(node.op, ast.Div):
            bad.append(f"true division at line {node.lineno}")
        elif isinstance(node, ast.Call) and getattr(node.func, "id", None) in ("float", "round"):
            bad.append(f"{node.func.id}() at line {node.lineno}")
        elif isinstance(node, ast.ImportFrom) and node.module == "math":
            if any(a.name not in INTEGER_MATH for a in node.names):  # isqrt is integer only
                bad.append(f"import of a float function from math at line {node.lineno}")
        elif isinstance(node, ast.Import | ast.ImportFrom):
            names = [a.name for a in node.names] + [getattr(node, "module", None) or ""]
            if any(n in ("math", "numpy", "fractions", "decimal") for n in names):
                bad.append(f"import of a float library at line {node.lineno}")
    return bad


def test_firmware_source_has_no_float_operation() -> None:
    for name in FIRMWARE_MODULES:
        path = ECU_DIR / f"{name}.py"
        bad = _float_nodes(ast.parse(path.read_text()))
        assert not bad, f"{path.name}: {bad}"


def test_no_float_value_is_ever_held_while_ticking() -> None:
    """Trace every line executed in the firmware modules and inspect every local variable (of
    the interpreted tick: compiled code makes no trace events; it runs the same source)."""
    if ecu.COMPILED:
        pure = {**os.environ, PURE_ENV: "1"}
        test = f"{__file__}::test_no_float_value_is_ever_held_while_ticking"
        done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                               test], env=pure, capture_output=True, text=True)  # fmt: skip
        assert done.returncode == 0, done.stdout[-3000:]
        return
    files = {str(ECU_DIR / f"{n}.py") for n in FIRMWARE_MODULES}
    seen: list[str] = []
    lines = [0]

    def tracer(frame: FrameType, event: str, arg: object):  # noqa: ANN202
        if frame.f_code.co_filename not in files:
            return None
        if event in ("line", "return"):
            lines[0] += 1
            for k, v in frame.f_locals.items():
                if isinstance(v, float) or (event == "return" and isinstance(arg, float)):
                    seen.append(f"{frame.f_code.co_name}:{frame.f_lineno} {k}={v!r}")
        return tracer

    inputs = scripted_inputs(4_000)
    ecu_, i = new_running_ecu()
    sys.settrace(tracer)
    try:
        _drive(ecu_, i, inputs, 0, 600)
        # speed jumps to overspeed: speed-sensor rate fault, substitution, overspeed trip
        _drive(ecu_, i, (array("i", [130_000]), inputs[1], inputs[2], inputs[3]), 600, 60)
    finally:
        sys.settrace(None)
    assert lines[0] > 50_000
    assert not seen, seen[:5]
    for name in EcuState.FIELDS:
        v = getattr(ecu_.s, name)
        assert isinstance(v, int) or (isinstance(v, array) and v.typecode == "i"), name
    for name in EcuOutputs.FIELDS:
        v = getattr(ecu_.out, name)
        assert isinstance(v, int) and -(1 << 31) <= v < 1 << 31, name


if __name__ == "__main__":  # (the interpreted tick's modules, for a compiled session)
    print(" ".join(sorted(_modules_run_by_ticks())))
