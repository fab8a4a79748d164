"""Generate ``generated/ecu_xcp_map.h``: what the C XCP slave (``ecu_xcp.c``) shares with the
Python one, written from the Python definitions (imported, never restated here):

- the numbers of XCP the slave speaks (:mod:`ecu.xcp.codes`) and the slave's own constants
  (:mod:`ecu.xcp.slave`, :mod:`ecu.xcp.daq`, :mod:`ecu.xcp.seed_key`, the service port's unlock
  secret);
- the memory map (:mod:`ecu.xcp.memory`): the regions' addresses, every parameter of the service
  port's table (:data:`ecu.service.param_table.TABLE`) with its raw limits, run safety and where
  the C slave keeps it, every measurement with its offset, type and source
  (:data:`ecu.xcp.memory.SOURCES`), the bench words, the axis points and the texts;
- the cross-parameter rules and the run record's layout (:mod:`ecu.port.xcp_run`).

``python -m ecu.port.codegen`` writes it with the other generated files; tests/port checks that
the committed file is a fresh generation.
"""

from __future__ import annotations

import re
import sys
from enum import IntEnum

from ecu.port.constants import GENERATED_DIR, ConstantsError, _c_int, _define, _module_ints

HEADER_NAME = "ecu_xcp_map.h"
TYPE_CODES = {"UBYTE": 0, "UWORD": 1, "SWORD": 2, "SLONG": 3}


def param_symbol(name: str) -> str:
    """``gamma_x[0]`` -> ``ECU_XCP_P_GAMMA_X_0``."""
    return "ECU_XCP_P_" + re.sub(r"\W+", "_", name).strip("_").upper()


def _enum_defines(prefix: str, enum: type[IntEnum]) -> list[str]:
    return [_define(f"{prefix}{m.name}", f"0x{int(m):02X}u") for m in enum]


def _codes() -> list[str]:
    from ecu.xcp import codes as C

    out = ["/* ASAM MCD-1 XCP 1.x as the slave speaks it (ecu.xcp.codes) */"]
    out += [_define(f"ECU_XCP_{n}", f"0x{v:02X}u") for n, v in _module_ints(C).items()]
    out += _enum_defines("ECU_XCP_CMD_", C.Cmd)
    out += _enum_defines("ECU_XCP_ERR_", C.Err)
    out += _enum_defines("ECU_XCP_EV_", C.Ev)
    return [*out, ""]


def _slave() -> list[str]:
    from ecu.service.message import UNLOCK_SECRET
    from ecu.xcp import codes as C
    from ecu.xcp import daq as D
    from ecu.xcp import seed_key
    from ecu.xcp import slave as S

    secret = UNLOCK_SECRET.decode("ascii")
    if not re.fullmatch(r"[ -~]*", secret) or '"' in secret or "\\" in secret:
        raise ConstantsError(f"unlock secret {secret!r}: not a plain C string")
    return [
        "/* the slave (ecu.xcp.slave, ecu.xcp.daq, ecu.xcp.seed_key) */",
        _define("ECU_XCP_MAX_CTO", str(S.MAX_CTO)),
        _define("ECU_XCP_MAX_DTO", str(S.MAX_DTO)),
        _define("ECU_XCP_MAX_FRAMES", str(S.MAX_FRAMES), "frames served per tick"),
        _define("ECU_XCP_MAX_CHECKSUM", str(S.MAX_CHECKSUM), "bytes per BUILD_CHECKSUM"),
        _define("ECU_XCP_PROTOCOL_VERSION", f"0x{S.PROTOCOL_VERSION:02X}u"),
        _define("ECU_XCP_TRANSPORT_VERSION", f"0x{S.TRANSPORT_VERSION:02X}u"),
        _define("ECU_XCP_DRIVER_VERSION", f"0x{S.DRIVER_VERSION:02X}u"),
        _define("ECU_XCP_EVENT_100MS", str(S.EVENT_100MS), "event 1's cycle, ms"),
        _define("ECU_XCP_DEFAULT_CMD_ID", f"0x{S.DEFAULT_IDS[0]:03X}u", "master -> ECU"),
        _define("ECU_XCP_DEFAULT_RES_ID", f"0x{S.DEFAULT_IDS[1]:03X}u", "ECU -> master"),
        _define("ECU_XCP_EVENTS", str(D.EVENTS)),
        _define("ECU_XCP_MAX_ODT_BYTES", str(D.MAX_ODT_BYTES)),
        _define("ECU_XCP_MAX_ENTRY_SIZE", str(D.MAX_ENTRY_SIZE)),
        _define("ECU_XCP_SEED_LENGTH", str(seed_key.SEED_LENGTH)),
        _define("ECU_XCP_KEY_LENGTH", str(seed_key.KEY_LENGTH)),
        _define("ECU_XCP_SECRET", f'"{secret}"', "the key's secret (ecu.service.message)"),
        "/* the commands served (ecu.xcp.slave.COMMANDS): X(command, minimum length, resource) */",
        "#define ECU_XCP_COMMAND_LIST(X) \\",
        *(
            f"    X(ECU_XCP_CMD_{C.Cmd(code).name}, {minimum}, 0x{resource:02X}u) \\"
            for code, (minimum, resource, _) in S.COMMANDS.items()
        ),
        "",
        "",
    ]


def _texts() -> list[str]:
    from ecu.port.xcp_run import ID_LEN
    from ecu.xcp import slave as S

    tail = {
        "A2L": S.A2L_NAME,
        "A2L_FILE": f"{S.A2L_NAME}.a2l",
        "EVENT0": "control tick",
        "EVENT1": "100 ms",
    }
    out = [
        "/* the text region: the identification (ECU_XCP_ID_LEN characters, the run's), then",
        "   these (ecu.xcp.slave.XcpSlave: the A2L's names, the event channels') */",
        _define("ECU_XCP_ID_LEN", str(ID_LEN)),
    ]
    at = ID_LEN
    for key, text in tail.items():
        out.append(_define(f"ECU_XCP_TEXT_{key}", str(at), f'"{text}"'))
        out.append(_define(f"ECU_XCP_TEXT_{key}_LEN", str(len(text))))
        at += len(text)
    out.append(_define("ECU_XCP_TEXT_TAIL", '"' + "".join(tail.values()) + '"'))
    out.append(_define("ECU_XCP_TEXT_SIZE", str(at)))
    return [*out, ""]


def _log_member(name: str) -> str:
    """A stored word of the logbook as a member of ecu_t: ``s.log_runs``,
    ``s.log_aborts[k]``."""
    prefix = "log_aborts_"
    if name.startswith(prefix):
        from ecu import logbook as L

        return f"s.log_aborts[{L.ABORT_NAMES.index(name[len(prefix) :])}]"
    return f"s.{name}"


def _memory() -> list[str]:
    from ecu import logbook as L
    from ecu.service.param_table import TABLE
    from ecu.xcp import memory as MEM

    out = [
        "/* the memory map (ecu.xcp.memory): regions' base addresses, little-endian, bytes */",
        _define("ECU_XCP_CAL_BASE", f"0x{MEM.CAL_BASE:08X}u", "the parameters, int32 raws"),
        _define("ECU_XCP_MEAS_BASE", f"0x{MEM.MEAS_BASE:08X}u", "the measurements"),
        _define("ECU_XCP_BENCH_BASE", f"0x{MEM.BENCH_BASE:08X}u", "arm, stop, throttle"),
        _define("ECU_XCP_LOG_BASE", f"0x{MEM.LOG_BASE:08X}u", "the logbook, int32 words"),
        _define("ECU_XCP_AXIS_BASE", f"0x{MEM.AXIS_BASE:08X}u", "the schedules' breakpoints"),
        _define("ECU_XCP_TEXT_BASE", f"0x{MEM.TEXT_BASE:08X}u", "identification and names"),
        _define("ECU_XCP_PARAMS", str(len(TABLE)), "parameters (ecu.service.param_table)"),
        _define("ECU_XCP_MEAS_SIZE", str(MEM.MEAS_SIZE), "bytes of the measurement region"),
        _define("ECU_XCP_MEASUREMENTS", str(len(MEM.MEASUREMENTS))),
        _define("ECU_XCP_BENCH_WORDS", str(len(MEM.BENCH))),
        _define("ECU_XCP_BENCH_ARM", str(MEM.BENCH_ARM)),
        _define("ECU_XCP_BENCH_STOP", str(MEM.BENCH_STOP)),
        _define("ECU_XCP_BENCH_THROTTLE", str(MEM.BENCH_THROTTLE)),
        _define("ECU_XCP_BENCH_TEST_LEVEL", str(MEM.BENCH_TEST_LEVEL)),
        _define("ECU_XCP_BENCH_TEST_MS", str(MEM.BENCH_TEST_MS)),
        _define("ECU_XCP_BENCH_TEST", str(MEM.BENCH_TEST)),
        _define("ECU_XCP_LOG_WORDS", str(len(MEM.LOGBOOK)), "the logbook's words"),
        "/* the logbook's words (ecu.logbook.word_names): X(member of ecu_t) */",
        "#define ECU_XCP_LOG_LIST(X) \\",
        *(
            f"    X({_log_member(name)}) /* {m.name} */ \\"
            for name, m in zip(L.word_names(), MEM.LOGBOOK, strict=True)
        ),
        "",
        _define("ECU_XCP_AXIS_POINTS", str(len(MEM.AXIS))),
        _define("ECU_XCP_AXIS", "{" + ", ".join(_c_int(v) for v in MEM.AXIS) + "}"),
        "",
    ]
    return out


def _parameters() -> list[str]:
    from ecu.port.xcp_run import IDENTITY, STORED, WORD
    from ecu.service.param_table import TABLE

    pairs: dict[tuple[int, int], int] = {}
    limit, store = [], []
    for spec in TABLE:
        pair = pairs.setdefault((spec.raw_lo, spec.raw_hi), len(pairs))
        identity = spec.name in IDENTITY
        limit.append(pair | (0x40 if spec.run_safe else 0) | (0x80 if identity else 0))
        store.append(WORD[IDENTITY[spec.name]] if identity else STORED.index(spec.name))
    if len(pairs) > 0x40 or max(store) > 0xFF:
        raise ConstantsError("the parameter table no longer fits its byte encoding")
    out = [
        "/* the parameters in table order (ecu.service.param_table.TABLE): raw limits, run safety",
        "   and where the C slave keeps each (its firmware word, or a slot of its own) */",
        "enum {",
        *(f"    {param_symbol(spec.name)} = {k}," for k, spec in enumerate(TABLE)),
        "};",
        _define("ECU_XCP_LIMIT_PAIRS", str(len(pairs)), "distinct (raw_lo, raw_hi)"),
        "#define ECU_XCP_LIMITS { \\",
        *(f"    {{{_c_int(lo)}, {_c_int(hi)}}}, \\" for lo, hi in pairs),
        "}",
        "/* per parameter: its limit pair | ECU_XCP_RUN_SAFE | ECU_XCP_IDENTITY */",
        _define("ECU_XCP_RUN_SAFE", "0x40u", "may change while in RUN"),
        _define("ECU_XCP_IDENTITY", "0x80u", "the raw is a firmware word"),
        "#define ECU_XCP_PARAM_LIMIT { \\",
        *_rows(limit),
        "}",
        "/* per parameter: the ecu_params_t word (ECU_XCP_IDENTITY), else its stored slot */",
        "#define ECU_XCP_PARAM_STORE { \\",
        *_rows(store),
        "}",
        _define("ECU_XCP_STORED", str(len(STORED)), "parameters that are no firmware word"),
        "",
    ]
    return out


def _rows(values: list[int], per_line: int = 16) -> list[str]:
    return [
        "    " + ", ".join(str(v) for v in values[k : k + per_line]) + ", \\"
        for k in range(0, len(values), per_line)
    ]


def _measurements() -> list[str]:
    from ecu.xcp import memory as MEM

    rows = []
    for k, m in enumerate(MEM.MEASUREMENTS):
        source = MEM.SOURCES[m.name]
        offset, kind = MEM.MEAS_OFFSETS[k], f"ECU_XCP_{m.datatype}"
        if source == MEM.SEQ_TIME:
            rows.append(f"    T({offset}, {kind}) /* {m.name} */ \\")
        elif source == MEM.DEMAND_SOURCE:
            rows.append(f"    B({offset}, {kind}) /* {m.name} */ \\")
        else:
            part, _, field = source.partition(".")
            member = {"s": f"s.{field}", "out": f"o.{field}", "t": f"{field}_q24"}[part]
            rows.append(f"    X({offset}, {kind}, {member}) /* {m.name} */ \\")
    return [
        "/* the measurements (ecu.xcp.memory.MEASUREMENTS, SOURCES): X(offset, type, member of",
        "   ecu_t), T(offset, type): the sequencer's time in ms, B(offset, type): the demand",
        "   source */",
        *(_define(f"ECU_XCP_{name}", str(code)) for name, code in TYPE_CODES.items()),
        "#define ECU_XCP_MEAS_LIST(X, T, B) \\",
        *rows,
        "",
        "",
    ]


def _rules() -> list[str]:
    from ecu.port import xcp_run as R
    from ecu.service.param_table import TABLE

    names = ("LT", "LE", "LE_OFF", "SUM_LE", "ZERO_OR_RANGE", "GE_MUL", "NONDECREASING", "BELOW")
    consts: list[int] = []
    rows = []
    for rule in R.RULES:
        kind = rule[0]
        a = param_symbol(rule[1])
        b = param_symbol(rule[2]) if kind not in (R.NONDECREASING,) else "0"
        spec_a = TABLE[R.INDEX[rule[1]]]
        c = "0"
        if kind == R.SUM_LE:
            c = param_symbol(rule[3])
        elif kind in (R.LE_OFF, R.ZERO_OR_RANGE):
            c = str(len(consts))
            for value in rule[3:]:
                consts.append(spec_a.to_raw(value))
        elif kind == R.GE_MUL:
            c = f"ECU_XCP_POOL_{rule[3]}"
        elif kind == R.NONDECREASING:
            b = str(sum(1 for s in TABLE if s.field == spec_a.field))
        elif kind == R.BELOW:
            c = str(sum(1 for s in TABLE if s.field == spec_a.field))
        rows.append(f"    R(ECU_XCP_RULE_{names[kind]}, {a}, {b}, {c}) \\")
    return [
        "/* cross-parameter rules of ecu.params.validate (ecu.port.xcp_run.RULES), raws A, B:",
        "   LT A < B, LE A <= B, LE_OFF A + K[c] <= B, SUM_LE A + B <= C, ZERO_OR_RANGE A == 0 or",
        "   K[c] <= A and A + K[c + 1] <= B, GE_MUL A >= fl(A's value * pool[c]) of B,",
        "   NONDECREASING A[0..b-1], BELOW A[k] < B[k] for k < c */",
        *(_define(f"ECU_XCP_RULE_{n}", str(k)) for k, n in enumerate(names)),
        "#define ECU_XCP_RULE_K {" + ", ".join(_c_int(v) for v in consts) + "}",
        "#define ECU_XCP_RULE_LIST(R) \\",
        *rows,
        "",
        "",
    ]


def _run_record() -> list[str]:
    from ecu.port import xcp_run as R

    out = [
        "/* the run record (ecu.port.xcp_run.run_record): int32 words at these offsets */",
        *(
            _define(f"ECU_XCP_{name}", str(getattr(R, name)))
            for name in (
                "RUN_ID",
                "RUN_STORED",
                "RUN_POOL",
                "RUN_WRITABLE",
                "RUN_BOUNDS",
                "RUN_RECIPES",
                "RUN_WORDS",
                "MAX_RECIPES",
                "MAX_BOUNDS",
                "POOL_SLOTS",
            )  # fmt: skip
        ),
        _define("ECU_XCP_OP_MUL", str(R.MUL)),
        _define("ECU_XCP_OP_DIV", str(R.DIV)),
        *(_define(f"ECU_XCP_POOL_{name}", str(k)) for k, name in enumerate(R.POOL)),
        "",
    ]
    return out


def header_text() -> str:
    lines = [
        "/*",
        " * ecu_xcp_map.h - what the C XCP slave shares with the Python one (ecu/xcp): XCP's",
        " * numbers, the memory map, the parameters' limits, the measurements, the rules and the",
        " * run record's layout. Generated by ecu/port/xcp_map.py (python -m ecu.port.codegen);",
        " * do not edit: tests/port fails when it differs from a fresh generation.",
        " */",
        "#ifndef ECU_XCP_MAP_H",
        "#define ECU_XCP_MAP_H",
        "",
        *_codes(),
        *_slave(),
        *_texts(),
        *_memory(),
        *_parameters(),
        *_measurements(),
        *_run_record(),
        *_rules(),
        "#endif /* ECU_XCP_MAP_H */",
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
