"""The ECU's memory as an XCP master sees it: fixed addresses, little-endian, byte granular.

- calibration, 0x20000000: every parameter of the service port's table
  (:data:`ecu.service.param_table.TABLE`) in table order, one int32 raw Q integer each (the
  fuel schedules' tables are consecutive: arrays); read, and written through the parameter
  checks;
- measurement, 0x20010000: the firmware's state after its last tick (:data:`MEASUREMENTS`), each
  in its own C type (UBYTE codes and flags, 16-bit words where the CAN contract's range fits,
  int32 otherwise), at an address aligned to its size; read only;
- bench, 0x20020000: the bench's arm, stop and throttle and its test functions (:data:`BENCH`),
  one int32 each; a read gives the bench's state, a write is the bench command;
- logbook, 0x20030000: the engine's logbook (ecu.logbook, :data:`LOGBOOK`), one int32 word
  each in its stored order; read only;
- axis points, 0x08000000: the fuel schedules' breakpoints, %N corrected (Q7.24); read only;
- text, 0x08001000: the identification, the A2L's name and the event channels' names (ASCII);
  read only.

A parameter's address is ``CAL_BASE + 4 * index``, a measurement's its place after those
before it (:func:`measurement_address`); new entries are only ever appended, so addresses stay
where they are. A measurement holds the firmware's value saturated to its type. The regions
are what an A2L describes (:mod:`ecu.xcp.a2l` writes it from these same tables). Reads are
served from a buffer per region: the calibration image is rebuilt when the parameter set
changes, the measurement image once per tick at most (when something reads it), so a read
costs a slice.
"""

from __future__ import annotations

import operator
import struct
from collections.abc import Callable
from dataclasses import dataclass

from ecu import actuator_tests as T
from ecu import logbook as L
from ecu import modes as M
from ecu import start_sequencer as Q
from ecu.firmware import Ecu
from ecu.params import SCHED_N0_PCT, SCHED_POINTS, SCHED_STEP_PCT
from ecu.service import bench_demand as BD
from ecu.service.bench_control import BenchControl
from ecu.service.param_table import TABLE, ParamTable

WORD = 4
CAL_BASE = 0x2000_0000
MEAS_BASE = 0x2001_0000
BENCH_BASE = 0x2002_0000
LOG_BASE = 0x2003_0000
AXIS_BASE = 0x0800_0000
TEXT_BASE = 0x0800_1000
Q24 = 1.0 / (1 << 24)

OWNER_NAMES = ("SPEED", "EGT_LIMIT", "ACCEL_LIMIT", "OVERSPEED_LIMIT", "DECEL_FLOOR")


# A2L data type -> (struct code, bytes, lowest, highest)
TYPES = {
    "UBYTE": ("B", 1, 0, 0xFF),
    "UWORD": ("H", 2, 0, 0xFFFF),
    "SWORD": ("h", 2, -0x8000, 0x7FFF),
    "SLONG": ("i", 4, -0x8000_0000, 0x7FFF_FFFF),
}


@dataclass(frozen=True)
class Measurement:
    """One value of the measurement region, of A2L type ``datatype``: physical value = raw *
    factor, in ``unit``; ``lo``..``hi`` its physical range; ``values`` names the raw codes of an
    enumeration."""

    name: str
    datatype: str
    description: str
    unit: str
    factor: float
    lo: float
    hi: float
    values: tuple[str, ...] = ()

    @property
    def size(self) -> int:
        return TYPES[self.datatype][1]


def _m(name: str, datatype: str, description: str, unit: str, factor: float, lo: float,
       hi: float, values: tuple[str, ...] = ()) -> Measurement:  # fmt: skip
    return Measurement(name, datatype, description, unit, factor, lo, hi, values)


I32 = 2147483647.0
U8, U16, S16, S32 = "UBYTE", "UWORD", "SWORD", "SLONG"
MEASUREMENTS: tuple[Measurement, ...] = (
    _m("ticks", S32, "ticks run since power-up", "", 1.0, 0, I32),
    _m("mode", U8, "ECU mode", "", 1.0, 0, 4, M.NAMES),
    _m("fault_word", U16, "fault word (ecu.faults)", "", 1.0, 0, 65535),
    _m(
        "speed",
        S16,
        "shaft speed used by the control (measured or substituted)",
        "%",
        0.01,
        -327.68,
        327.67,
    ),  # fmt: skip
    _m("speed_rpm", S32, "shaft speed as read", "rpm", 1.0, 0, 262143),
    _m("speed_ref", S16, "reference-model speed", "%", 0.01, -327.68, 327.67),
    _m("speed_rate", S32, "speed rate (central difference or observer)", "%/s", Q24, -128, 128),
    _m("egt", S16, "EGT as read", "K", 0.1, 0, 1638.3),
    _m(
        "egt_gas",
        S32,
        "gas temperature estimate (EGT lead; 0: no reading yet)",
        "K",
        0.1 / 4096,
        0,
        5000,
    ),  # fmt: skip
    _m("pump_voltage", S16, "pump voltage command", "V", 0.001, -32.768, 32.767),
    _m("pump_duty", S16, "pump PWM duty", "%", 0.01, 0, 100),
    _m("pump_enable", U8, "pump driver enable", "", 1.0, 0, 1),
    _m("supply", U16, "supply voltage", "V", 0.001, 0, 65.535),
    _m("pump_current", U16, "pump current", "A", 0.001, 0, 65.535),
    _m("pump_health", S32, "pump health (Lambda-hat / commissioned)", "%", 0.1, 0, 100000),
    _m("owner", U8, "loop owning the pump command", "", 1.0, 0, 4, OWNER_NAMES),
    _m("seq_state", U8, "start/stop sequencer step", "", 1.0, 0, 8, Q.NAMES),
    _m("seq_reason", U8, "last start's abort reason", "", 1.0, 0, 6, Q.REASONS),
    _m("seq_time", S32, "time in the sequencer's step", "s", 0.001, 0, I32 / 1000),
    _m("starter", S16, "starter PWM duty", "%", 0.01, 0, 100),
    _m("igniter", U8, "igniter on", "", 1.0, 0, 1),
    _m("ap21", S32, "estimate A_p21", "1/s2", Q24, -128, 128),
    _m("ap22", S32, "estimate A_p22", "1/s", Q24, -128, 128),
    _m("lambda", S32, "estimate Lambda", "%/(V s2)", Q24, -128, 128),
    _m("theta21", S32, "estimate Theta_f21", "", Q24, -128, 128),
    _m("theta22", S32, "estimate Theta_f22", "", Q24, -128, 128),
    _m("kx1", S32, "MRAC gain K_x1", "V/%", Q24, -128, 128),
    _m("kx2", S32, "MRAC gain K_x2", "V s/%", Q24, -128, 128),
    _m("kr", S32, "MRAC gain K_r", "V/%", Q24, -128, 128),
    _m("kf1", S32, "MRAC gain K_f1", "", Q24, -128, 128),
    _m("kf2", S32, "MRAC gain K_f2", "", Q24, -128, 128),
    _m(
        "obs_speed_dev", S32, "fast-model observer: speed deviation from trim", "%", Q24, -128, 128
    ),  # fmt: skip
    _m("obs_speed_rate", S32, "fast-model observer: speed rate", "%/s", Q24, -128, 128),
    _m("sat_events", S32, "saturations since power-up", "", 1.0, 0, I32),
    _m("inputs_valid", U8, "valid speed and EGT readings since power-up", "", 1.0, 0, 1),
    _m("demand", S32, "speed demand in force", "%", Q24, -128, 128),
    _m("demand_source", U8, "demand source", "", 1.0, 0, 2, BD.SOURCE_NAMES),
    _m("egt_start_target", S16, "the start's EGT target on the day", "K", 0.1, 0, 3276.7),
    _m("test_active", U8, "the bench test function running", "", 1.0, 0, 3, T.NAMES),
    _m("test_time_left", U16, "the bench test's time left", "ms", 1.0, 0, 65535),
)
MEAS_INDEX = {m.name: k for k, m in enumerate(MEASUREMENTS)}


def _layout(measurements: tuple[Measurement, ...]) -> tuple[tuple[int, ...], str, int]:
    """Offsets (each aligned to its size), the struct format with its pad bytes, the size."""
    offsets, fmt, at = [], "<", 0
    for m in measurements:
        pad = -at % m.size
        fmt += "x" * pad + TYPES[m.datatype][0]
        at += pad
        offsets.append(at)
        at += m.size
    pad = -at % WORD
    return tuple(offsets), fmt + "x" * pad, at + pad


MEAS_OFFSETS, _MEAS_FORMAT, MEAS_SIZE = _layout(MEASUREMENTS)
_MEAS = struct.Struct(_MEAS_FORMAT)
_BOUNDS = tuple((TYPES[m.datatype][2], TYPES[m.datatype][3]) for m in MEASUREMENTS)


# where each measurement comes from after the tick: an attribute of the firmware (``s``: its
# state, ``out``: its outputs, ``t``: the tick's variables), or the two that are computed: the
# sequencer's time in ms and the bench's demand source. The C slave reads the same fields of
# its ecu_t (ecu/port/xcp_map.py generates its table from this one).
SEQ_TIME = "s.seq_timer ms"  # s.seq_timer * 1000 // rate_hz
DEMAND_SOURCE = "bench.source"
SOURCES: dict[str, str] = {
    "ticks": "s.ticks", "mode": "out.mode", "fault_word": "out.fault_word", "speed": "out.n_cpct",
    "speed_rpm": "s.speed_rpm", "speed_ref": "out.nref_cpct", "speed_rate": "t.rate",
    "egt": "s.egt_dk", "egt_gas": "s.egt_lead_q12", "pump_voltage": "out.pump_mv",
    "pump_duty": "out.duty_cpct", "pump_enable": "out.pump_enable", "supply": "s.supply_mv",
    "pump_current": "s.pump_ma", "pump_health": "out.pump_health_pm", "owner": "out.owner",
    "seq_state": "out.seq_state", "seq_reason": "out.seq_reason", "seq_time": SEQ_TIME,
    "starter": "out.starter_cpct", "igniter": "out.igniter", "ap21": "out.ap21_q24",
    "ap22": "out.ap22_q24", "lambda": "out.lambda_q24", "theta21": "out.theta21_q24",
    "theta22": "out.theta22_q24", "kx1": "out.kx1_q24", "kx2": "out.kx2_q24", "kr": "out.kr_q24",
    "kf1": "out.kf1_q24", "kf2": "out.kf2_q24", "obs_speed_dev": "s.obs_n_q24",
    "obs_speed_rate": "s.obs_v_q24", "sat_events": "out.sat_events",
    "inputs_valid": "out.inputs_valid", "demand": "s.demand_q24",
    "demand_source": DEMAND_SOURCE, "egt_start_target": "s.seq_target_dk",
    "test_active": "s.test_active", "test_time_left": "s.test_time_left_ms",
}  # fmt: skip
if tuple(SOURCES) != tuple(m.name for m in MEASUREMENTS):
    raise RuntimeError("ecu.xcp.memory: SOURCES must name every measurement, in order")
_PATHS = tuple(
    "s.seq_timer" if src == SEQ_TIME else "s.ticks" if src == DEMAND_SOURCE else src
    for src in SOURCES.values()
)
_READ = operator.attrgetter(*_PATHS)
_SEQ_TIME = tuple(SOURCES.values()).index(SEQ_TIME)
_DEMAND_SOURCE = tuple(SOURCES.values()).index(DEMAND_SOURCE)


def measure(ecu: Ecu, demand_source: int) -> list[int]:
    """The measurement region's values after the ECU's last tick, in :data:`MEASUREMENTS`
    order (from :data:`SOURCES`)."""
    values = list(_READ(ecu))
    values[_SEQ_TIME] = values[_SEQ_TIME] * 1000 // ecu.p.rate_hz
    values[_DEMAND_SOURCE] = demand_source
    return values


# the logbook region: the stored words of ecu.logbook in their order (int32 each), under the
# names the A2L gives them (the EGT and speed without their units' suffixes)
LOGBOOK: tuple[Measurement, ...] = (
    _m("log_runs", S32, "engine runs (entries into RUN; a relight stays in its run)", "", 1.0, 0,
       I32),
    _m("log_run_time_s", S32, "time in RUN, whole seconds", "s", 1.0, 0, I32),
    _m("log_run_frac_ticks", S32, "ticks of the second in RUN under way", "", 1.0, 0, 10000),
    _m("log_starts", S32, "arms that began a start", "", 1.0, 0, I32),
    *(
        _m(f"log_aborts_{name}", S32, f"starts aborted: {name.upper()}", "", 1.0, 0, I32)
        for name in L.ABORT_NAMES
    ),
    _m("log_last_max_egt", S32, "the last run's highest EGT", "K", 0.1, 0, 1638.3),
    _m("log_last_max_speed", S32, "the last run's highest speed", "%", 0.01, 0, 327.67),
    _m("log_last_shutdown", S32, "why the last start or run ended", "", 1.0, 0,
       len(L.SHUTDOWN_NAMES) - 1, L.SHUTDOWN_NAMES),
)  # fmt: skip
if len(LOGBOOK) != len(L.word_names()):
    raise RuntimeError("ecu.xcp.memory: LOGBOOK must name every stored word of ecu.logbook")


@dataclass(frozen=True)
class BenchWord:
    name: str
    description: str
    unit: str
    factor: float
    lo: float
    hi: float


# the bench region: what a read gives, what a write does
BENCH: tuple[BenchWord, ...] = (
    BenchWord("bench_arm", "read: the bench's arm; write 1: arm (start the engine)", "", 1.0, 0, 1),
    BenchWord("bench_stop", "read: a stop held; write 1: stop (always accepted)", "", 1.0, 0, 1),
    BenchWord("bench_throttle", "read: the bench's speed demand; write: the throttle (0: idle)",
              "%", 0.01, 0, 120),
    BenchWord("bench_test_level", "the next test's level: pump prime mV, starter duty 0.01 %",
              "", 1.0, 0, 10000),
    BenchWord("bench_test_ms", "the next test's duration", "ms", 1.0, 0, 15000),
    BenchWord("bench_test", "read: the test running (0 none); write 1 glow plug, 2 starter "
              "spin, 3 pump prime (in OFF), 0 end the test", "", 1.0, 0, 3),
)  # fmt: skip
BENCH_ARM, BENCH_STOP, BENCH_THROTTLE, BENCH_TEST_LEVEL, BENCH_TEST_MS, BENCH_TEST = range(6)

# the fuel schedules' breakpoints: %N corrected, Q7.24
AXIS_NAME = "sched_speed_axis"
AXIS = tuple(round((SCHED_N0_PCT + k * SCHED_STEP_PCT) * (1 << 24)) for k in range(SCHED_POINTS))


@dataclass
class Region:
    """``size`` bytes from ``base``: ``image()`` gives them as they are now."""

    name: str
    base: int
    size: int
    writable: bool
    image: Callable[[], bytes | bytearray]

    @property
    def end(self) -> int:
        return self.base + self.size


class Texts:
    """Read-only ASCII texts, one after the other from TEXT_BASE; each found by its key."""

    def __init__(self, texts: dict[str, str]) -> None:
        self.data = bytearray()
        self.at: dict[str, tuple[int, int]] = {}  # key -> (address, length)
        for key, text in texts.items():
            raw = text.encode("ascii")
            self.at[key] = (TEXT_BASE + len(self.data), len(raw))
            self.data += raw


class MemoryMap:
    """The regions of one ECU (its firmware, parameter table and bench)."""

    def __init__(
        self, ecu: Ecu, table: ParamTable, bench: BenchControl, texts: dict[str, str]
    ) -> None:
        self.ecu = ecu
        self.table = table
        self.bench = bench
        self.texts = Texts(texts)
        self._cal = bytearray(WORD * len(TABLE))
        self._cal_version = -1
        self._meas = bytearray(MEAS_SIZE)
        self._meas_tick = -1
        self._bench = bytearray(WORD * len(BENCH))
        self._log = bytearray(WORD * len(LOGBOOK))
        axis = struct.pack(f"<{len(AXIS)}i", *AXIS)
        text = bytes(self.texts.data)
        self.calibration = Region("calibration", CAL_BASE, len(self._cal), True, self._cal_image)
        self.measurement = Region(
            "measurement", MEAS_BASE, len(self._meas), False, self._meas_image
        )
        self.bench_region = Region("bench", BENCH_BASE, len(self._bench), True, self._bench_image)
        self.regions = (
            Region("axis points", AXIS_BASE, len(axis), False, lambda: axis),
            Region("text", TEXT_BASE, len(text), False, lambda: text),
            self.calibration,
            self.measurement,
            self.bench_region,
            Region("logbook", LOG_BASE, len(self._log), False, self._log_image),
        )

    def locate(self, address: int, size: int) -> Region | None:
        """The region holding all of ``address`` .. ``address + size`` (None: none does)."""
        for region in self.regions:
            if region.base <= address and address + size <= region.end:
                return region
        return None

    def read(self, address: int, size: int) -> bytes | None:
        region = self.locate(address, size)
        if region is None:
            return None
        start = address - region.base
        return bytes(region.image()[start : start + size])

    def _cal_image(self) -> bytearray:
        table = self.table
        if table.version != self._cal_version:
            struct.pack_into(f"<{len(TABLE)}i", self._cal, 0, *table.raws())
            self._cal_version = table.version
        return self._cal

    def _meas_image(self) -> bytearray:
        """The measurements of the last tick, each saturated to its type, packed once per
        tick."""
        ticks = self.ecu.s.ticks
        if ticks != self._meas_tick:
            values = [
                lo if v < lo else hi if v > hi else v
                for v, (lo, hi) in zip(measure(self.ecu, self.bench.source), _BOUNDS, strict=True)
            ]
            _MEAS.pack_into(self._meas, 0, *values)
            self._meas_tick = ticks
        return self._meas

    def invalidate(self) -> None:
        """Measurements changed outside a tick (the bench's demand source): repack them."""
        self._meas_tick = -1

    def _bench_image(self) -> bytearray:
        b = self.bench
        d = b.demand
        struct.pack_into(
            "<6i", self._bench, 0, d.arm if d.engaged else 0, int(b.stop_held), d.throttle_cpct,
            b.test_level, b.test_ms, self.ecu.s.test_active,
        )  # fmt: skip
        return self._bench

    def _log_image(self) -> bytearray:
        """The logbook's words as the firmware holds them now."""
        struct.pack_into(f"<{len(LOGBOOK)}i", self._log, 0, *L.stored_words(self.ecu.s))
        return self._log


def logbook_address(index: int) -> int:
    return LOG_BASE + WORD * index


def parameter_address(index: int) -> int:
    return CAL_BASE + WORD * index


def measurement_address(index: int) -> int:
    return MEAS_BASE + MEAS_OFFSETS[index]


def bench_address(index: int) -> int:
    return BENCH_BASE + WORD * index
