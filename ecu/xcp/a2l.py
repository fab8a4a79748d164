"""The ECU's A2L (ASAM MCD-2 MC 1.7), written from the tables the slave serves.

Every parameter of the service port's table is a CHARACTERISTIC at its calibration address: a
VALUE, or for the fuel schedules' tables a CURVE over the AXIS_PTS of their breakpoints (%N
corrected); the bench's arm, stop and throttle are VALUEs in the bench region; every
measurement is a MEASUREMENT. The conversions come from each value's Q format: LINEAR with the
factor 2^-frac (or the unit's scale, 0.01 %N, 0.1 K, ...), value tables (TAB_VERB) for modes,
states and reasons. MOD_PAR gives the memory segments and the EPK (the slave's identification,
at its address); IF_DATA XCP the protocol layer, the DAQ processor with its two events and
XCP_ON_CAN with the identifiers. An A2ML block declares the part of XCP's IF_DATA grammar this
file uses, so that tools that check IF_DATA against it (CANape, INCA) can read it.

    text = a2l_text()                    # for the default rate (100 Hz) and the DBC's IDs
    text = a2l_text(rate_hz=200, ids=(0x600, 0x601))
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from ecu.params import SCHED_POINTS, EcuParams
from ecu.service.param_table import TABLE, ParamSpec
from ecu.service.port import FIRMWARE, build_id
from ecu.xcp import daq as D
from ecu.xcp import memory as MEM
from ecu.xcp import slave as S

ASAP2_VERSION = (1, 71)
SCHEDULES = ("accel_line_v", "decel_floor_v", "accel_rate_pct_s")
T_MS = 2000  # T1..T7: the master's timeouts
BAUDRATE = 500_000
FORMAT = "%12.6"

A2ML = """
    /begin A2ML
      struct Protocol_Layer {
        uint; uint; uint; uint; uint; uint; uint; uint;  /* version, T1 .. T7 [ms] */
        uchar;  /* MAX_CTO */
        uint;  /* MAX_DTO */
        enum { "BYTE_ORDER_MSB_LAST" = 0, "BYTE_ORDER_MSB_FIRST" = 1 };
        enum {
          "ADDRESS_GRANULARITY_BYTE" = 1, "ADDRESS_GRANULARITY_WORD" = 2,
          "ADDRESS_GRANULARITY_DWORD" = 4
        };
        taggedstruct {
          ("OPTIONAL_CMD" enum {
            "GET_COMM_MODE_INFO" = 0xFB, "GET_ID" = 0xFA, "SET_REQUEST" = 0xF9,
            "GET_SEED" = 0xF8, "UNLOCK" = 0xF7, "SET_MTA" = 0xF6, "UPLOAD" = 0xF5,
            "SHORT_UPLOAD" = 0xF4, "BUILD_CHECKSUM" = 0xF3, "TRANSPORT_LAYER_CMD" = 0xF2,
            "USER_CMD" = 0xF1, "DOWNLOAD" = 0xF0, "DOWNLOAD_NEXT" = 0xEF, "DOWNLOAD_MAX" = 0xEE,
            "SHORT_DOWNLOAD" = 0xED, "MODIFY_BITS" = 0xEC, "SET_CAL_PAGE" = 0xEB,
            "GET_CAL_PAGE" = 0xEA, "GET_PAG_PROCESSOR_INFO" = 0xE9, "GET_SEGMENT_INFO" = 0xE8,
            "GET_PAGE_INFO" = 0xE7, "SET_SEGMENT_MODE" = 0xE6, "GET_SEGMENT_MODE" = 0xE5,
            "COPY_CAL_PAGE" = 0xE4, "CLEAR_DAQ_LIST" = 0xE3, "SET_DAQ_PTR" = 0xE2,
            "WRITE_DAQ" = 0xE1, "SET_DAQ_LIST_MODE" = 0xE0, "GET_DAQ_LIST_MODE" = 0xDF,
            "START_STOP_DAQ_LIST" = 0xDE, "START_STOP_SYNCH" = 0xDD, "GET_DAQ_CLOCK" = 0xDC,
            "READ_DAQ" = 0xDB, "GET_DAQ_PROCESSOR_INFO" = 0xDA, "GET_DAQ_RESOLUTION_INFO" = 0xD9,
            "GET_DAQ_LIST_INFO" = 0xD8, "GET_DAQ_EVENT_INFO" = 0xD7, "FREE_DAQ" = 0xD6,
            "ALLOC_DAQ" = 0xD5, "ALLOC_ODT" = 0xD4, "ALLOC_ODT_ENTRY" = 0xD3
          })*;
          "COMMUNICATION_MODE_SUPPORTED" taggedunion {
            "BLOCK" taggedstruct {
              "SLAVE";
              "MASTER" struct { uchar; uchar; };  /* MAX_BS, MIN_ST */
            };
            "INTERLEAVED" uchar;  /* QUEUE_SIZE */
          };
          "SEED_AND_KEY_EXTERNAL_FUNCTION" char[256];
        };
      };
      struct Daq {
        enum { "STATIC" = 0, "DYNAMIC" = 1 };
        uint;  /* MAX_DAQ */
        uint;  /* MAX_EVENT_CHANNEL */
        uchar;  /* MIN_DAQ */
        enum {
          "OPTIMISATION_TYPE_DEFAULT" = 0, "OPTIMISATION_TYPE_ODT_TYPE_16" = 1,
          "OPTIMISATION_TYPE_ODT_TYPE_32" = 2, "OPTIMISATION_TYPE_ODT_TYPE_64" = 3,
          "OPTIMISATION_TYPE_ODT_TYPE_ALIGNMENT" = 4, "OPTIMISATION_TYPE_MAX_ENTRY_SIZE" = 5
        };
        enum {
          "ADDRESS_EXTENSION_FREE" = 0, "ADDRESS_EXTENSION_ODT" = 1, "ADDRESS_EXTENSION_DAQ" = 3
        };
        enum {
          "IDENTIFICATION_FIELD_TYPE_ABSOLUTE" = 0, "IDENTIFICATION_FIELD_TYPE_RELATIVE_BYTE" = 1,
          "IDENTIFICATION_FIELD_TYPE_RELATIVE_WORD" = 2,
          "IDENTIFICATION_FIELD_TYPE_RELATIVE_WORD_ALIGNED" = 3
        };
        enum {
          "GRANULARITY_ODT_ENTRY_SIZE_DAQ_BYTE" = 1, "GRANULARITY_ODT_ENTRY_SIZE_DAQ_WORD" = 2,
          "GRANULARITY_ODT_ENTRY_SIZE_DAQ_DWORD" = 4, "GRANULARITY_ODT_ENTRY_SIZE_DAQ_DLONG" = 8
        };
        uchar;  /* MAX_ODT_ENTRY_SIZE_DAQ */
        enum {
          "NO_OVERLOAD_INDICATION" = 0, "OVERLOAD_INDICATION_PID" = 1,
          "OVERLOAD_INDICATION_EVENT" = 2
        };
        taggedstruct {
          "PRESCALER_SUPPORTED";
          "RESUME_SUPPORTED";
          block "TIMESTAMP_SUPPORTED" struct {
            uint;  /* TIMESTAMP_TICKS */
            enum { "NO_TIME_STAMP" = 0, "SIZE_BYTE" = 1, "SIZE_WORD" = 2, "SIZE_DWORD" = 4 };
            enum {
              "UNIT_1NS" = 0, "UNIT_10NS" = 1, "UNIT_100NS" = 2, "UNIT_1US" = 3,
              "UNIT_10US" = 4, "UNIT_100US" = 5, "UNIT_1MS" = 6, "UNIT_10MS" = 7,
              "UNIT_100MS" = 8, "UNIT_1S" = 9
            };
            taggedstruct { "TIMESTAMP_FIXED"; };
          };
          (block "EVENT" struct {
            char[101];  /* EVENT_CHANNEL_NAME */
            char[9];  /* EVENT_CHANNEL_SHORT_NAME */
            uint;  /* EVENT_CHANNEL_NUMBER */
            enum { "DAQ" = 1, "STIM" = 2, "DAQ_STIM" = 3 };
            uchar;  /* MAX_DAQ_LIST */
            uchar;  /* EVENT_CHANNEL_TIME_CYCLE */
            uchar;  /* EVENT_CHANNEL_TIME_UNIT */
            uchar;  /* EVENT_CHANNEL_PRIORITY */
          })*;
        };
      };
      struct CAN_Parameters {
        uint;  /* XCP on CAN version */
        taggedstruct {
          "CAN_ID_BROADCAST" ulong;
          "CAN_ID_MASTER" ulong;
          "CAN_ID_SLAVE" ulong;
          "BAUDRATE" ulong;
          "SAMPLE_POINT" uchar;
          "MAX_DLC_REQUIRED";
        };
      };
      taggedstruct Common_Parameters {
        block "PROTOCOL_LAYER" struct Protocol_Layer;
        block "DAQ" struct Daq;
      };
      block "IF_DATA" taggedunion if_data {
        "XCP" struct {
          taggedstruct Common_Parameters;
          taggedstruct {
            block "XCP_ON_CAN" struct {
              struct CAN_Parameters;
              taggedstruct Common_Parameters;
            };
          };
        };
      };
    /end A2ML"""

OPTIONAL_CMDS = (
    "GET_COMM_MODE_INFO", "GET_ID", "SET_REQUEST", "GET_SEED", "UNLOCK", "SET_MTA", "UPLOAD",
    "SHORT_UPLOAD", "BUILD_CHECKSUM", "DOWNLOAD", "DOWNLOAD_NEXT", "CLEAR_DAQ_LIST",
    "SET_DAQ_PTR", "WRITE_DAQ", "SET_DAQ_LIST_MODE", "GET_DAQ_LIST_MODE", "START_STOP_DAQ_LIST",
    "START_STOP_SYNCH", "GET_DAQ_CLOCK", "READ_DAQ", "GET_DAQ_PROCESSOR_INFO",
    "GET_DAQ_RESOLUTION_INFO", "GET_DAQ_LIST_INFO", "GET_DAQ_EVENT_INFO", "FREE_DAQ",
    "ALLOC_DAQ", "ALLOC_ODT", "ALLOC_ODT_ENTRY",
)  # fmt: skip


def a2l_name(name: str) -> str:
    """A parameter's name as an A2L identifier: ``gamma_x[1]`` -> ``gamma_x_1``."""
    return re.sub(r"\[(\d+)\]", r"_\1", name)


def _number(x: float) -> str:
    """A number as A2L writes it: integers plain, others with all their digits."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else repr(float(x))


def _text(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


@dataclass(frozen=True)
class Conversion:
    """A COMPU_METHOD: LINEAR phys = factor * raw (or a value table), with its unit."""

    factor: float
    unit: str
    values: tuple[str, ...] = ()
    table: str = ""  # the value table's name (TAB_VERB)

    @property
    def name(self) -> str:
        if self.values:
            return f"CM_{self.table}"
        exponent = -math.log2(self.factor) if self.factor > 0 else 0.0
        if self.factor == 1.0:
            label = "IDENT"
        elif exponent.is_integer():
            label = f"Q{int(exponent)}"
        else:
            label = "F" + f"{self.factor:g}".replace(".", "_").replace("-", "m")
        unit = re.sub(r"[^A-Za-z0-9]+", "_", self.unit.replace("%", "pct")).strip("_")
        return f"CM_{label}" + (f"_{unit}" if unit else "")

    def block(self) -> str:
        unit = _text(self.unit)
        if self.values:
            return (
                f'    /begin COMPU_METHOD {self.name} {_text(self.table)} TAB_VERB "%4.0" '
                f"{unit}\n      COMPU_TAB_REF VT_{self.table}\n    /end COMPU_METHOD"
            )
        return (
            f'    /begin COMPU_METHOD {self.name} "raw * {_number(self.factor)}" LINEAR '
            f'"{FORMAT}" {unit}\n      COEFFS_LINEAR {_number(self.factor)} 0\n'
            "    /end COMPU_METHOD"
        )

    def vtab(self) -> str:
        pairs = " ".join(f"{k} {_text(v)}" for k, v in enumerate(self.values))
        return (
            f"    /begin COMPU_VTAB VT_{self.table} {_text(self.table)} TAB_VERB "
            f"{len(self.values)}\n      {pairs}\n    /end COMPU_VTAB"
        )


def _spec_conversion(spec: ParamSpec) -> Conversion:
    return Conversion(1.0 / (1 << spec.frac_bits), "" if spec.unit in ("-", "bool") else spec.unit)


def _value(name: str, text: str, address: int, conv: Conversion, lo: float, hi: float,
           read_only: bool = False) -> str:  # fmt: skip
    return (
        f"    /begin CHARACTERISTIC {name} {_text(text)} VALUE 0x{address:08X} RL_VALUE_SLONG "
        f"0 {conv.name} {_number(lo)} {_number(hi)}\n"
        + ("      READ_ONLY\n" if read_only else "")
        + f'      FORMAT "{FORMAT}"\n'
        + (f"      PHYS_UNIT {_text(conv.unit)}\n" if conv.unit else "")
        + "    /end CHARACTERISTIC"
    )


def _curve(name: str, address: int, spec: ParamSpec, conv: Conversion, axis: Conversion) -> str:
    lo_axis, hi_axis = MEM.AXIS[0] * axis.factor, MEM.AXIS[-1] * axis.factor
    text = _text(f"{name}: fuel schedule against corrected speed")
    return (
        f"    /begin CHARACTERISTIC {name} {text} CURVE 0x{address:08X} RL_CURVE_SLONG 0 "
        f"{conv.name} {_number(spec.lo)} {_number(spec.hi)}\n"
        f"      /begin AXIS_DESCR COM_AXIS NO_INPUT_QUANTITY {axis.name} {SCHED_POINTS} "
        f"{_number(lo_axis)} {_number(hi_axis)}\n"
        f"        AXIS_PTS_REF {MEM.AXIS_NAME}\n"
        "      /end AXIS_DESCR\n"
        f'      FORMAT "{FORMAT}"\n'
        + (f"      PHYS_UNIT {_text(conv.unit)}\n" if conv.unit else "")
        + "    /end CHARACTERISTIC"
    )


def characteristics() -> list[tuple[str, int, int]]:
    """(A2L name, address, bytes) of every CHARACTERISTIC and AXIS_PTS, as the A2L gives them."""
    out: list[tuple[str, int, int]] = []
    for k, spec in enumerate(TABLE):
        if spec.field in SCHEDULES:
            if spec.element == 0:
                out.append((spec.field, MEM.parameter_address(k), 4 * SCHED_POINTS))
        else:
            out.append((a2l_name(spec.name), MEM.parameter_address(k), 4))
    out += [(w.name, MEM.bench_address(k), 4) for k, w in enumerate(MEM.BENCH)]
    return out


def a2l_text(
    rate_hz: int | None = None,
    ids: tuple[int, int] = S.DEFAULT_IDS,
    limits: S.Limits = S.Limits(),  # noqa: B008 (frozen)
    read_only: frozenset[str] = frozenset(),
) -> str:
    """The A2L of this firmware and slave, for an ECU ticking at ``rate_hz`` (default: the
    parameters' default) with the XCP identifiers ``ids`` (master to ECU, ECU to master) and a
    slave that holds ``limits`` (the C slave's are smaller: ``ecu.port.xcp.header_limits``);
    the parameters of ``read_only`` (names as in the table) are READ_ONLY: the slave refuses
    to write them (the C slave those it cannot recompute on the target)."""
    rate_hz = rate_hz or EcuParams().rate_hz
    identification = f"{FIRMWARE} build {build_id()}"
    epk_address = MEM.TEXT_BASE  # the slave's texts start with its identification
    conversions: dict[str, Conversion] = {}
    body: list[str] = []

    def use(conv: Conversion) -> Conversion:
        conversions.setdefault(conv.name, conv)
        return conv

    axis_conv = use(Conversion(1.0 / (1 << 24), "%"))
    body.append(
        f"    /begin AXIS_PTS {MEM.AXIS_NAME} \"the fuel schedules' breakpoints: speed "
        f"corrected to the day's inlet\" 0x{MEM.AXIS_BASE:08X} NO_INPUT_QUANTITY RL_AXIS_SLONG "
        f"0 {axis_conv.name} {SCHED_POINTS} {_number(MEM.AXIS[0] * axis_conv.factor)} "
        f"{_number(MEM.AXIS[-1] * axis_conv.factor)}\n"
        "      READ_ONLY\n"
        f'      FORMAT "{FORMAT}"\n      PHYS_UNIT "%"\n'
        "    /end AXIS_PTS"
    )
    for k, spec in enumerate(TABLE):
        conv = use(_spec_conversion(spec))
        address = MEM.parameter_address(k)
        if spec.field in SCHEDULES:
            if spec.element == 0:
                body.append(_curve(spec.field, address, spec, conv, axis_conv))
            continue
        fixed = spec.name in read_only
        run = ("read only on this ECU" if fixed else
               "may change in RUN" if spec.run_safe else "refused in RUN")  # fmt: skip
        body.append(_value(a2l_name(spec.name), f"{spec.name} ({run})", address, conv,
                           spec.lo, spec.hi, fixed))  # fmt: skip
    for k, word in enumerate(MEM.BENCH):
        conv = use(Conversion(word.factor, word.unit))
        body.append(_value(word.name, word.description, MEM.bench_address(k), conv, word.lo,
                           word.hi))  # fmt: skip
    measurements = [(m, MEM.measurement_address(k)) for k, m in enumerate(MEM.MEASUREMENTS)]
    measurements += [(m, MEM.logbook_address(k)) for k, m in enumerate(MEM.LOGBOOK)]
    for m, address in measurements:
        conv = use(Conversion(m.factor, m.unit, m.values, m.name if m.values else ""))
        body.append(
            f"    /begin MEASUREMENT {m.name} {_text(m.description)} {m.datatype} {conv.name} 1 0 "
            f"{_number(m.lo)} {_number(m.hi)}\n"
            f"      ECU_ADDRESS 0x{address:08X}\n"
            f'      FORMAT "{FORMAT}"\n'
            + (f"      PHYS_UNIT {_text(m.unit)}\n" if m.unit else "")
            + "    /end MEASUREMENT"
        )
    compu = [c.block() for c in conversions.values()]
    vtabs = [c.vtab() for c in conversions.values() if c.values]
    return "\n".join(
        [
            f"ASAP2_VERSION {ASAP2_VERSION[0]} {ASAP2_VERSION[1]}",
            f'/begin PROJECT {S.A2L_NAME} "Small-turbojet ECU (turbojet-sil)"',
            '  /begin HEADER "written by sil a2l from the firmware\'s tables"',
            f"    VERSION {_text(identification)}",
            "    PROJECT_NO TURBOJET",
            "  /end HEADER",
            f'  /begin MODULE {S.A2L_NAME} "the ECU firmware and its XCP slave on CAN"',
            A2ML,
            _mod_common(),
            _mod_par(identification, epk_address),
            _if_data(rate_hz, ids, limits),
            _record_layouts(),
            *compu,
            *vtabs,
            *body,
            "  /end MODULE",
            "/end PROJECT",
            "",
        ]
    )


def _mod_common() -> str:
    return (
        '    /begin MOD_COMMON "little-endian (Intel), byte-aligned"\n'
        "      BYTE_ORDER MSB_LAST\n"
        "      ALIGNMENT_BYTE 1\n      ALIGNMENT_WORD 1\n      ALIGNMENT_LONG 1\n"
        "      ALIGNMENT_INT64 1\n"
        "      ALIGNMENT_FLOAT32_IEEE 1\n      ALIGNMENT_FLOAT64_IEEE 1\n"
        "    /end MOD_COMMON"
    )


def _mod_par(identification: str, epk_address: int) -> str:
    segments = [
        ("Calibration", "parameters (raw Q integers)", "CALIBRATION_VARIABLES", "RAM",
         MEM.CAL_BASE, 4 * len(TABLE)),
        ("Measurement", "the firmware's state after its last tick", "VARIABLES", "RAM",
         MEM.MEAS_BASE, MEM.MEAS_SIZE),
        ("Bench", "the bench's arm, stop and throttle", "VARIABLES", "RAM", MEM.BENCH_BASE,
         4 * len(MEM.BENCH)),
        ("Logbook", "the engine's logbook (read only)", "VARIABLES", "RAM", MEM.LOG_BASE,
         4 * len(MEM.LOGBOOK)),
        ("AxisPoints", "the fuel schedules' breakpoints", "DATA", "FLASH", MEM.AXIS_BASE,
         4 * len(MEM.AXIS)),
    ]  # fmt: skip
    lines = [
        '    /begin MOD_PAR "the ECU\'s memory as its XCP slave serves it"',
        f"      VERSION {_text(identification)}",
        f"      ADDR_EPK 0x{epk_address:08X}",
        f"      EPK {_text(identification)}",
        '      SUPPLIER "turbojet-sil"',
        '      CPU_TYPE "Cortex-M4 (emulated: the Python tick)"',
    ]
    for name, text, kind, memory, base, size in segments:
        lines.append(
            f"      /begin MEMORY_SEGMENT {name} {_text(text)} {kind} {memory} INTERN "
            f"0x{base:08X} 0x{size:X} -1 -1 -1 -1 -1\n      /end MEMORY_SEGMENT"
        )
    lines.append("    /end MOD_PAR")
    return "\n".join(lines)


def _if_data(rate_hz: int, ids: tuple[int, int], limits: S.Limits) -> str:
    cycle_ms = 1000 // rate_hz
    optional = "\n".join(f"        OPTIONAL_CMD {c}" for c in OPTIONAL_CMDS)
    return f"""    /begin IF_DATA XCP
      /begin PROTOCOL_LAYER
        0x0100 {T_MS} {T_MS} {T_MS} {T_MS} {T_MS} {T_MS} {T_MS} {S.MAX_CTO} {S.MAX_DTO}
        BYTE_ORDER_MSB_LAST ADDRESS_GRANULARITY_BYTE
{optional}
        COMMUNICATION_MODE_SUPPORTED BLOCK MASTER {limits.max_bs} 0
      /end PROTOCOL_LAYER
      /begin DAQ
        DYNAMIC {limits.max_daq} {D.EVENTS} 0 OPTIMISATION_TYPE_DEFAULT ADDRESS_EXTENSION_FREE
        IDENTIFICATION_FIELD_TYPE_ABSOLUTE GRANULARITY_ODT_ENTRY_SIZE_DAQ_BYTE
        {D.MAX_ENTRY_SIZE} NO_OVERLOAD_INDICATION
        PRESCALER_SUPPORTED
        /begin TIMESTAMP_SUPPORTED
          1 SIZE_DWORD UNIT_1US TIMESTAMP_FIXED
        /end TIMESTAMP_SUPPORTED
        /begin EVENT
          "control tick" "tick" 0 DAQ 255 {cycle_ms} 6 1
        /end EVENT
        /begin EVENT
          "100 ms" "100ms" 1 DAQ 255 {S.EVENT_100MS} 6 0
        /end EVENT
      /end DAQ
      /begin XCP_ON_CAN
        0x0100
        CAN_ID_MASTER 0x{ids[0]:X}
        CAN_ID_SLAVE 0x{ids[1]:X}
        BAUDRATE {BAUDRATE}
      /end XCP_ON_CAN
    /end IF_DATA"""


def _record_layouts() -> str:
    return "\n".join(
        [
            "    /begin RECORD_LAYOUT RL_VALUE_SLONG\n      FNC_VALUES 1 SLONG COLUMN_DIR DIRECT"
            "\n    /end RECORD_LAYOUT",
            "    /begin RECORD_LAYOUT RL_CURVE_SLONG\n      FNC_VALUES 1 SLONG COLUMN_DIR DIRECT"
            "\n    /end RECORD_LAYOUT",
            "    /begin RECORD_LAYOUT RL_AXIS_SLONG\n      AXIS_PTS_X 1 SLONG INDEX_INCR DIRECT"
            "\n    /end RECORD_LAYOUT",
        ]
    )
