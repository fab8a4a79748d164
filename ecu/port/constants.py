"""Generate ``generated/ecu_constants.h``: every constant the C port shares with the Python
firmware and the CAN contract, written from their definitions (imported, never restated here).

- record sizes, theta slots, modes, sequencer states, abort reasons, controllers, E2E statuses,
  loop owners, fault bits and the firmware's scaling and limits: from the Python modules that
  define them (``ecu.state``, ``ecu.modes``, ``ecu.start_sequencer``, ``ecu.params``,
  ``ecu.firmware``, ``ecu.limiters``, ``ecu.faults``, ``ecu.inlet``, ``ecu.pi_design``,
  ``ecu.fixedpoint``);
- frame IDs, E2E data IDs and the raw range of every signal the ECU packs: from the DBC,
  through :class:`protocol.codec.Codec` (which loads it with ``protocol.dbc.load_database``), so
  that the C frames saturate exactly where the Python codec does;
- the alive counter's modulo (``protocol.e2e``) and the counter step the ECU node still accepts
  (the checkers of ``ecu.node.EcuNode``).

The public names of ``ecu_core.h`` (``ECU_OFF``, ``ECU_SEQ_*``, ``ECU_ABORT_*``, ``ECU_CTRL_*``,
``ECU_E2E_*``, ``ECU_AP21``..., ``ECU_N_THETA``...) and of ``ecu_frames.h`` (``ECU_FRAME_*``,
``ECU_TELEMETRY_COUNT``) are defined here; everything else has the ``ECU_`` prefix too, so the
header can be included by integrators' code without clashing.

    python -m ecu.port.constants    rewrite generated/ecu_constants.h (python -m ecu.port.codegen
                                    rewrites it together with the frame code)
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterable
from pathlib import Path
from types import ModuleType

from cantools.database.can.c_source import camel_to_snake_case

from ecu.compiled_tick import source_file
from protocol.dbc import DBC_PATH

HEADER_NAME = "ecu_constants.h"
GENERATED_DIR = Path(__file__).resolve().parent / "generated"
INT32_MIN = -(1 << 31)
INT32_MAX = (1 << 31) - 1

# the C names of the ECU's frames (ecu_frames.h ECU_FRAME_*) -> their DBC messages
FRAMES = {
    "DEMAND": "Demand",
    "SENSORS": "PlantSensors",
    "ANALOG": "PlantAnalog",
    "ACTUATOR": "EcuActuator",
    "STARTER": "EcuStarter",
    "STATUS": "EcuStatus",
    "TELEMETRY": "EcuTelemetry",
}
# the frames the ECU packs: the raw range of each of their signals (E2E fields aside)
PACKED = ("EcuActuator", "EcuStarter", "EcuStatus", "EcuTelemetry")


class ConstantsError(RuntimeError):
    """The Python definitions and the DBC disagree, or a value does not fit the C type."""


def _c_int(value: int) -> str:
    """An int32 value as a C integer constant of type int (INT32_MIN without a long literal)."""
    if not INT32_MIN <= value <= INT32_MAX:
        raise ConstantsError(f"{value} does not fit an int32")
    if value == INT32_MIN:
        return "(-2147483647 - 1)"
    return f"({value})" if value < 0 else str(value)


def _bits(value: int) -> str:
    """A bit mask as a hex int constant (4 digits for the 16-bit fault word)."""
    if not 0 <= value <= INT32_MAX:
        raise ConstantsError(f"bit mask {value} does not fit a non-negative int32")
    return f"0x{value:04X}"


def _define(name: str, value: str, comment: str = "") -> str:
    line = f"#define {name} {value}"
    return f"{line:<48} /* {comment} */" if comment else line


def _enum(comment: str, members: Iterable[tuple[str, int]]) -> list[str]:
    members = list(members)
    values = [v for _, v in members]
    if values != list(range(len(values))):
        raise ConstantsError(f"{comment}: values {values} are not 0, 1, 2, ...")
    body = ",\n".join(f"    {name} = {value}" for name, value in members)
    return [f"/* {comment} */", "enum {", body, "};", ""]


def _snake(name: str) -> str:
    return camel_to_snake_case(name).upper()


def _module_ints(module: ModuleType) -> dict[str, int]:
    """The upper-case int constants a module assigns at its top level (not those it imports),
    read from its source, with their values from the module."""
    tree = ast.parse(source_file(module).read_text())
    names = [
        target.id
        for node in tree.body
        if isinstance(node, ast.Assign)
        for target in node.targets
        if isinstance(target, ast.Name) and target.id.isupper()
    ]
    return {n: getattr(module, n) for n in names if type(getattr(module, n)) is int}


def _python_sections() -> list[str]:
    from ecu import (
        actuator_tests,
        fixedpoint,
        inlet,
        limiters,
        logbook,
        modes,
        params,
        pi_design,
        state,
    )
    from ecu import faults as F
    from ecu import firmware as FW
    from ecu import start_sequencer as Q
    from protocol.e2e import E2EStatus

    out: list[str] = []
    out += [
        "/* array lengths of the X-macro lists (plain decimal literals: ecu_core.c writes them",
        "   into the field names the Python wrapper reads) */",
        _define("ECU_N_THETA", str(state.N_THETA), "ecu.state.N_THETA: theta slots"),
        _define("ECU_PI_POINTS", str(pi_design.PI_POINTS), "ecu.pi_design.PI_POINTS"),
        _define("ECU_SCHED_POINTS", str(params.SCHED_POINTS), "ecu.params.SCHED_POINTS"),
        _define(
            "ECU_RATE_BUF_LEN", str(params.RATE_BUF_LEN), "ecu.params.RATE_BUF_LEN: speed ring"
        ),
        _define("ECU_LOG_ABORTS", str(params.LOG_ABORTS), "ecu.params.LOG_ABORTS: logbook aborts"),
        "",
    ]
    slots = sorted((v, k) for k, v in _module_ints(state).items() if k != "N_THETA")
    if [v for v, _ in slots] != list(range(state.N_THETA)):
        raise ConstantsError(f"ecu.state slots {slots} are not 0..N_THETA-1")
    out += _enum("slots of theta_q24 / theta_ext (ecu.state)", ((f"ECU_{k}", v) for v, k in slots))
    out += _enum("modes (ecu.modes)", ((f"ECU_{n}", getattr(modes, n)) for n in modes.NAMES))
    out += _enum(
        "start/stop sequencer states (ecu.start_sequencer)",
        ((f"ECU_SEQ_{n}", getattr(Q, n)) for n in Q.NAMES),
    )
    reasons = [(n, Q.NO_ABORT if n == "NONE" else getattr(Q, n)) for n in Q.REASONS]
    out += _enum(
        "start abort reasons (ecu.start_sequencer)", ((f"ECU_ABORT_{n}", v) for n, v in reasons)
    )
    out += _enum(
        "the last shutdown's reason in the logbook (ecu.logbook SD_*)",
        ((f"ECU_SD_{n}", getattr(logbook, f"SD_{n}")) for n in logbook.SHUTDOWN_NAMES),
    )
    out += _enum(
        "bench test functions (ecu.actuator_tests)",
        ((f"ECU_TEST_{n}", getattr(actuator_tests, n)) for n in actuator_tests.NAMES),
    )
    out += [
        "/* the longest test of each kind, ms, and of all in ticks (ecu.actuator_tests) */",
        *(
            _define(f"ECU_TEST_MAX_MS_{n}", _c_int(actuator_tests.MAX_MS[k]))
            for k, n in enumerate(actuator_tests.NAMES)
            if k
        ),
        _define("ECU_TEST_MAX_TICKS", _c_int(actuator_tests.MAX_TICKS)),
        "",
    ]
    out += _enum(
        "controllers (ecu.params CTRL_*, in the order of ecu.params.CONTROLLERS)",
        (
            (f"ECU_CTRL_{n.upper()}", getattr(params, f"CTRL_{n.upper()}"))
            for n in params.CONTROLLERS
        ),
    )
    e2e = [(s.name, getattr(FW, f"E2E_{s.name}")) for s in E2EStatus]
    if any(v != s.value for (_, v), s in zip(e2e, E2EStatus, strict=True)):
        raise ConstantsError("ecu.firmware E2E_* differ from protocol.e2e.E2EStatus")
    out += _enum(
        "E2E receiver status per frame kind (ecu.firmware E2E_*): OK, a fresh valid frame whose\n"
        "   values are used; REPEATED, WRONGSEQUENCE, WRONGCRC, rejected frames whose values are\n"
        "   not used; NONEWDATA, nothing arrived",
        ((f"ECU_E2E_{n}", v) for n, v in e2e),
    )
    owners = sorted((v, k) for k, v in _module_ints(limiters).items() if k.startswith("OWNER_"))
    out += _enum(
        "the loop that owns the pump command (ecu.limiters OWNER_*)",
        ((f"ECU_{k}", v) for v, k in owners),
    )
    out.append("/* fault word bits (ecu.faults) */")
    for bit, name in sorted(F.NAMES.items()):
        out.append(_define(f"ECU_FAULT_{name}", _bits(bit)))
    transient = " ".join(F.NAMES[b] for b in sorted(F.NAMES) if F.TRANSIENT & b)
    trip = " ".join(F.NAMES[b] for b in sorted(F.NAMES) if FW.TRIP_FAULT & b)
    out += [
        "/* the bits that describe the current tick only (ecu.faults.TRANSIENT):",
        f"   {transient} */",
        _define("ECU_FAULT_TRANSIENT", _bits(F.TRANSIENT)),
        "/* the trips that end in FAULT (ecu.firmware.TRIP_FAULT):",
        f"   {trip} */",
        _define("ECU_FAULT_TRIP", _bits(FW.TRIP_FAULT)),
        "",
        "/* ecu_state_t.inputs_seen: the sensors that gave a valid reading since power-up",
        "   (ecu.firmware SEEN_*) */",
        _define("ECU_SEEN_SPEED", _c_int(FW.SEEN_SPEED)),
        _define("ECU_SEEN_EGT", _c_int(FW.SEEN_EGT)),
        _define("ECU_SEEN_ALL", _c_int(FW.SEEN_ALL)),
        "",
        "/* scaling and limits */",
        _define(
            "ECU_ACC_EXT_BITS",
            _c_int(fixedpoint.ACC_EXT_BITS),
            "ecu.fixedpoint: split accumulator extension",
        ),
        _define("ECU_RPM_PER_PCT", _c_int(FW.RPM_PER_PCT), "ecu.firmware: rpm per %N"),
        _define("ECU_AGE_MAX", _bits(FW.AGE_MAX), "ecu.firmware: frame ages saturate here"),
        _define(
            "ECU_EGT_ERROR_MAX_DK", _c_int(params.EGT_ERROR_MAX_DK), "ecu.params: EGT loop error"
        ),
        _define("ECU_RATE_MAX_HZ", _c_int(params.RATE_MAX_HZ), "ecu.params: highest ECU rate"),
        _define(
            "ECU_DUTY_FULL_CPCT",
            _c_int(Q.DUTY_FULL_CPCT),
            "ecu.start_sequencer: 100 % duty",
        ),
        _define("ECU_T_STD_CK", _c_int(inlet.T_STD_CK), "ecu.inlet: standard day, 0.01 K"),
        _define("ECU_INLET_MIN_DK", _c_int(inlet.INLET_MIN_DK), "ecu.inlet: day's inlet range"),
        _define("ECU_INLET_MAX_DK", _c_int(inlet.INLET_MAX_DK), "(ecu.params.INLET_RANGE_K)"),
        "",
    ]
    _check_inlet(inlet.T_STD_CK, inlet.INLET_MIN_DK, inlet.INLET_MAX_DK)
    return out


def _check_inlet(t_std_ck: int, min_dk: int, max_dk: int) -> None:
    """What take_egt_at_rest (ecu_core.c) relies on; ecu_core.c asserts it again when compiled."""
    if not 0 < t_std_ck < (1 << 15):
        raise ConstantsError(f"T_STD_CK {t_std_ck}: T_STD_CK << 48 must fit an int64")
    if not 0 < min_dk <= max_dk or max_dk * 10 > INT32_MAX:
        raise ConstantsError(f"inlet range {min_dk}..{max_dk} dK")
    if (t_std_ck << 48) // (min_dk * 10) >= 1 << 62:
        raise ConstantsError("1 / sqrt(theta) at the coldest inlet does not fit an int32")


def _dbc_sections(dbc_path: Path) -> list[str]:
    from ecu.node import TELEMETRY_COUNT, EcuNode
    from protocol.codec import Codec
    from protocol.e2e import COUNTER_MODULO

    codec = Codec(dbc_path)
    out = [
        "/* the ECU's frames: standard IDs (DBC) */",
        *(
            _define(f"ECU_FRAME_{name}", f"0x{codec[msg].frame_id:03X}u", msg)
            for name, msg in FRAMES.items()
        ),
        "",
        "/* E2E data IDs of the ECU's frames (DBC attribute E2EDataID) */",
        *(
            _define(f"ECU_E2E_DATA_ID_{name}", f"{codec[msg].data_id}u", msg)
            for name, msg in FRAMES.items()
        ),
        "",
    ]
    node = EcuNode()
    max_delta = {c.max_delta for c in (node.sensors_check, node.analog_check, node.demand_check)}
    if len(max_delta) != 1:
        raise ConstantsError(f"ecu.node's checkers accept different counter steps: {max_delta}")
    telemetry = codec["EcuTelemetry"]
    if telemetry.mux_layout.raw_max + 1 != TELEMETRY_COUNT:
        raise ConstantsError(
            f"ecu.node.TELEMETRY_COUNT {TELEMETRY_COUNT} vs the DBC's TelemetryIndex 0.."
            f"{telemetry.mux_layout.raw_max}"
        )
    fault_word = next(s for s in codec["EcuStatus"].signals if s.name == "FaultWord")
    if fault_word.raw_min != 0 or fault_word.raw_max & (fault_word.raw_max + 1):
        raise ConstantsError(f"EcuStatus.FaultWord's range is not a bit mask: {fault_word}")
    out += [
        "/* E2E: the alive counter runs 0..COUNTER_MODULO - 1 (protocol.e2e.COUNTER_MODULO); a",
        "   counter step of 1..MAX_DELTA is OK (the checkers of ecu.node.EcuNode) */",
        _define("ECU_E2E_COUNTER_MODULO", _c_int(COUNTER_MODULO)),
        _define("ECU_E2E_MAX_DELTA", _c_int(max_delta.pop())),
        "",
        "/* the fault word's width on the bus (EcuStatus.FaultWord) */",
        _define("ECU_FAULT_WORD_MASK", _bits(fault_word.raw_max)),
        "",
        "/* EcuTelemetry's multiplexed values, one per frame (ecu.node.TELEMETRY_COUNT) */",
        _define("ECU_TELEMETRY_COUNT", str(TELEMETRY_COUNT)),
        "",
        "/* raw range of every signal the ECU packs (ECU_RAW_<MESSAGE>_<SIGNAL>_MIN / _MAX), as",
        "   the Python codec saturates them (protocol.codec: the DBC range in raw units, kept",
        "   inside the physical range) */",
    ]
    for msg in PACKED:
        m = codec[msg]
        layouts = [m.mux_layout, *m.mux_signals.values()] if m.multiplexed else list(m.signals)
        for s in layouts:
            stem = f"ECU_RAW_{_snake(msg)}_{_snake(s.name)}"
            out.append(_define(f"{stem}_MIN", _c_int(s.raw_min)))
            out.append(_define(f"{stem}_MAX", _c_int(s.raw_max)))
    out.append("")
    return out


def header_text(dbc_path: Path = DBC_PATH) -> str:
    """The text of generated/ecu_constants.h."""
    lines = [
        "/*",
        " * ecu_constants.h - the constants the C port shares with the Python firmware and the CAN",
        " * contract (protocol/turbojet.dbc). Generated by ecu/port/constants.py (python -m",
        " * ecu.port.codegen writes it with the frame code); do not edit: tests/port/test_build.py",
        " * fails when it differs from a fresh generation.",
        " */",
        "#ifndef ECU_CONSTANTS_H",
        "#define ECU_CONSTANTS_H",
        "",
        *_python_sections(),
        *_dbc_sections(dbc_path),
        "#endif /* ECU_CONSTANTS_H */",
        "",
    ]
    return "\n".join(lines)


def main() -> int:
    GENERATED_DIR.mkdir(exist_ok=True)
    path = GENERATED_DIR / HEADER_NAME
    path.write_text(header_text())
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
