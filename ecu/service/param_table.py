"""The parameters a service tool may read and write: names, Q formats, units, limits, run safety.

Each entry maps a name to an :class:`ecu.params.EcuParams` field (``gamma_x[1]`` is the second
element of a pair). On the wire a value is its raw Q-format integer ``round(value * 2**frac_bits)``;
the entry's limits are checked on that integer. A write is refused when it is out of limits, when
the parameter is unsafe to change while the engine runs and the ECU is in RUN, or when the whole
set then fails :func:`ecu.params.validate` (a cross-field rule, named in the message). An accepted
write recompiles the firmware constants (:func:`ecu.firmware_params.compile_params`), which
apply from the next tick. This is configuration-time code (floats), outside the control tick.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import msgpack

from ecu.firmware_params import FirmwareParams, compile_params
from ecu.logbook import STORE_KEY
from ecu.params import SCHED_POINTS, EcuParams
from ecu.service.crc import crc16


@dataclass(frozen=True)
class ParamSpec:
    name: str  # field, or field[index] for an element of a pair or table
    unit: str
    frac_bits: int  # Q format: value = raw / 2**frac_bits
    lo: float  # limits in engineering units
    hi: float
    run_safe: bool  # may change while the engine runs (mode RUN)

    @property
    def field(self) -> str:
        return self.name.partition("[")[0]

    @property
    def element(self) -> int | None:
        _, bracket, rest = self.name.partition("[")
        return int(rest.rstrip("]")) if bracket else None

    @property
    def raw_lo(self) -> int:
        return math.ceil(self.lo * (1 << self.frac_bits))

    @property
    def raw_hi(self) -> int:
        return math.floor(self.hi * (1 << self.frac_bits))

    def to_raw(self, value: float) -> int:
        return round(value * (1 << self.frac_bits))

    def to_value(self, raw: int) -> float:
        return raw / (1 << self.frac_bits)


def _s(name: str, unit: str, frac: int, lo: float, hi: float, run_safe: bool) -> ParamSpec:
    return ParamSpec(name, unit, frac, lo, hi, run_safe)


Q24 = 24  # Q7.24, as the firmware's signals and parameters
Q16 = 16  # Q15.16 where the range needs it (temperatures in K)

TABLE: tuple[ParamSpec, ...] = (
    # tuning that may change in RUN: gains, learning rates, limiter settings
    _s("pid_kp", "V/%N", Q24, 0.0, 20.0, True),
    _s("pid_ki", "V/(%N s)", Q24, 0.0, 20.0, True),
    _s("pid_kd", "V s/%N", Q24, 0.0, 10.0, True),
    _s("gamma_x[0]", "-", Q24, 0.0, 10.0, True),
    _s("gamma_x[1]", "-", Q24, 0.0, 10.0, True),
    _s("gamma_r", "-", Q24, 0.0, 10.0, True),
    _s("gamma_f[0]", "-", Q24, 0.0, 10.0, True),
    _s("gamma_f[1]", "-", Q24, 0.0, 10.0, True),
    _s("gamma_a[0]", "-", Q24, 0.0, 50.0, True),
    _s("gamma_a[1]", "-", Q24, 0.0, 50.0, True),
    _s("gamma_lambda", "-", Q24, 0.0, 10.0, True),
    _s("gamma_theta[0]", "-", Q24, 0.0, 100.0, True),
    _s("gamma_theta[1]", "-", Q24, 0.0, 100.0, True),
    _s("gamma_b", "-", Q24, 0.0, 10.0, True),
    _s("p12", "-", Q24, 0.0, 50.0, True),
    _s("egt_limit_k", "K", Q16, 800.0, 1400.0, True),
    _s("egt_kp", "V/K", Q24, 0.0, 1.0, True),
    _s("egt_ki", "V/(K s)", Q24, 0.0, 1.0, True),
    _s("accel_max_pct_s", "%N/s", Q24, 1.0, 50.0, True),
    _s("decel_max_pct_s", "%N/s", Q24, 1.0, 60.0, True),
    _s("pump_health_alarm", "-", Q24, 0.1, 0.99, True),
    _s("adapt_band_pct", "%N", Q24, 0.0, 60.0, True),
    # unsafe while the engine runs: trim point, protection levels, actuator range, model
    _s("trim_n_pct", "%N", Q24, 50.0, 100.0, False),
    _s("trim_v", "V", Q24, 1.0, 25.0, False),
    _s("entry_v", "V", Q24, 1.0, 25.0, False),
    _s("idle_pct", "%N", Q24, 20.0, 60.0, False),
    _s("demand_max_pct", "%N", Q24, 50.0, 105.0, False),
    _s("n_limit_pct", "%N", Q24, 90.0, 108.0, False),
    _s("overspeed_pct", "%N", Q24, 95.0, 110.0, False),
    _s("egt_max_k", "K", Q16, 900.0, 1500.0, False),
    _s("egt_lead_tau_s", "s", Q16, 0.0, 5.0, False),  # what the EGT limiter sees
    _s("egt_lead_filter_s", "s", Q16, 0.0, 5.0, False),
    _s("egt_gas_margin_k", "K", Q16, 0.0, 200.0, False),  # the gas over the limit, in a transient
    _s("egt_zero_fuel_k", "K", Q16, 0.0, 1000.0, False),  # the gas at no fuel: the EGT line
    _s("v_min", "V", Q24, 0.0, 10.0, False),
    _s("v_max", "V", Q24, 5.0, 30.0, False),
    _s("v_slew_v_s", "V/s", Q24, 1.0, 100.0, False),
    _s("duty_max", "-", Q24, 0.1, 1.0, False),
    _s("lambda_commissioned", "-", Q24, 0.1, 20.0, False),
    _s("pump_dead_v", "V", Q24, 0.0, 10.0, False),
    _s("pump_scaling_on", "bool", 0, 0, 1, False),
    _s("ref_wn", "rad/s", Q24, 0.5, 20.0, False),
    _s("ref_zeta", "-", Q24, 0.3, 2.0, False),
    _s("mrac_cmd_lag_s", "s", Q16, 0.0, 5.0, False),
    _s("limiters_on", "bool", 0, 0, 1, False),
    _s("rate_filter_on", "bool", 0, 0, 1, False),
    _s("rate_filter_bw", "rad/s", Q24, 2.0, 50.0, False),
    # fuel schedules: breakpoints at 45, 50, ..., 100 %N corrected (ecu.params.SCHED_POINTS);
    # a set whose tables fall or cross is refused whole (ecu.params.validate)
    _s("fuel_schedules_on", "bool", 0, 0, 1, False),
    _s("inlet_temp_k", "K", Q16, 223.0, 333.0, False),
    _s("inlet_from_egt", "bool", 0, 0, 1, False),
    *(_s(f"accel_line_v[{k}]", "V", Q24, 0.0, 30.0, False) for k in range(SCHED_POINTS)),
    *(_s(f"decel_floor_v[{k}]", "V", Q24, 0.0, 30.0, False) for k in range(SCHED_POINTS)),
    *(_s(f"accel_rate_pct_s[{k}]", "%N/s", Q24, 0.5, 100.0, False) for k in range(SCHED_POINTS)),
    # the start/stop sequencer (ecu.start_sequencer) and flameout detection; the order of the
    # speeds and temperatures is checked as a set (ecu.params.validate)
    _s("start_on", "bool", 0, 0, 1, False),
    _s("start_duty", "-", Q24, 0.05, 1.0, False),
    _s("start_purge_s", "s", Q16, 0.1, 60.0, False),
    _s("start_ignition_pct", "%N", Q24, 0.5, 30.0, False),
    _s("start_spinup_timeout_s", "s", Q16, 0.5, 120.0, False),
    _s("start_ign_v0", "V", Q24, 0.1, 10.0, False),
    _s("start_ign_v_rate", "V/s", Q24, 0.01, 5.0, False),
    _s("start_ign_v_max", "V", Q24, 0.2, 15.0, False),
    _s("start_light_rise_k", "K", Q16, 5.0, 300.0, False),
    _s("start_light_track_k_s", "K/s", Q16, 1.0, 200.0, False),
    _s("start_ignition_timeout_s", "s", Q16, 1.0, 60.0, False),
    _s("start_igniter_hold_s", "s", Q16, 0.1, 30.0, False),
    _s("start_starter_ramp_s", "s", Q16, 0.1, 30.0, False),
    _s("start_ramp_v_rate", "V/s", Q24, 0.01, 5.0, False),
    _s("start_accel_pct_s", "%N/s", Q24, 0.2, 20.0, False),
    _s("start_egt_target_k", "K", Q16, 400.0, 1400.0, False),
    _s("start_egt_limit_k", "K", Q16, 400.0, 1500.0, False),
    _s("start_egt_margin_k", "K", Q16, 0.0, 500.0, False),
    _s("start_cutoff_pct", "%N", Q24, 5.0, 60.0, False),
    _s("start_ramp_timeout_s", "s", Q16, 1.0, 120.0, False),
    _s("start_idle_pct", "%N", Q24, 10.0, 60.0, False),
    _s("start_stabilise_timeout_s", "s", Q16, 1.0, 120.0, False),
    _s("relight_max", "-", 0, 0, 5, False),
    _s("cool_duty", "-", Q24, 0.05, 1.0, True),
    _s("cool_egt_k", "K", Q16, 300.0, 500.0, True),
    _s("cool_rearm_k", "K", Q16, 1.0, 200.0, True),
    _s("cool_soak_s", "s", Q16, 0.1, 300.0, True),
    _s("cool_speed_pct", "%N", Q24, 5.0, 60.0, True),
    _s("cool_timeout_s", "s", Q16, 1.0, 300.0, True),
    _s("flameout_egt_k", "K", Q16, 300.0, 900.0, False),
    _s("flameout_egt_time_s", "s", Q16, 0.05, 5.0, False),
)
BY_NAME = {spec.name: spec for spec in TABLE}


class WriteRefused(ValueError):
    """A write the ECU refuses; ``reason`` is the service status name, the message names the
    parameter."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def _value(params: EcuParams, spec: ParamSpec) -> float:
    v = getattr(params, spec.field)
    return float(v if spec.element is None else v[spec.element])


def _with(params: EcuParams, spec: ParamSpec, value: float) -> EcuParams:
    if spec.element is not None:
        pair = list(getattr(params, spec.field))
        pair[spec.element] = value
        return replace(params, **{spec.field: tuple(pair)})
    if spec.frac_bits == 0:
        return replace(params, **{spec.field: type(getattr(params, spec.field))(int(value))})
    return replace(params, **{spec.field: value})


class ParamTable:
    """The live parameter set of one ECU (engineering record and compiled constants)."""

    def __init__(self, params: EcuParams) -> None:
        self.commit(params, compile_params(params))

    def raw(self, name: str) -> int:
        return self._raws[self.spec(name).name]

    @staticmethod
    def spec(name: str) -> ParamSpec:
        try:
            return BY_NAME[name]
        except KeyError:
            raise WriteRefused("UNKNOWN_PARAM", f"unknown parameter {name!r}") from None

    def check_write(self, name: str, raw: int, running: bool) -> tuple[EcuParams, FirmwareParams]:
        """The set with ``name`` written, compiled; :class:`WriteRefused` says why not."""
        return self.check_writes(((name, raw),), running)

    def check_writes(
        self, writes: Sequence[tuple[str, int]], running: bool
    ) -> tuple[EcuParams, FirmwareParams]:
        """The set with every (name, raw) of ``writes`` written (each in its limits, none unsafe
        in RUN while ``running``), checked and compiled once as a whole (so that a table may be
        written whole although one of its points alone would make it fall); :class:`WriteRefused`
        says why not, naming the first parameter refused."""
        params = self.params
        for name, raw in writes:
            spec = self.spec(name)
            if not spec.raw_lo <= raw <= spec.raw_hi:
                raise WriteRefused(
                    "OUT_OF_RANGE",
                    f"{name}={spec.to_value(raw):g} {spec.unit}: outside its limits "
                    f"[{spec.lo:g}, {spec.hi:g}]",
                )
            if running and not spec.run_safe:
                raise WriteRefused("REFUSED_IN_RUN", f"{name}: unsafe to change while in RUN")
            params = _with(params, spec, spec.to_value(raw))
        try:
            return params, compile_params(params)
        except (ValueError, ArithmeticError) as exc:
            names = ", ".join(name for name, _ in writes)
            raise WriteRefused(
                "INVALID", f"{names}: refused by the parameter checks: {exc}"
            ) from None

    def commit(self, params: EcuParams, firmware: FirmwareParams) -> None:
        self.params = params
        self.firmware = firmware
        self._raws = {spec.name: spec.to_raw(_value(params, spec)) for spec in TABLE}
        self._image = msgpack.packb(self._raws)
        self._crc = crc16(self._image)
        self.version = getattr(self, "version", -1) + 1  # counts the sets committed

    def raws(self) -> list[int]:
        """Every parameter's raw value, in table order."""
        return list(self._raws.values())

    def image(self) -> bytes:
        """The set as stored in flash: msgpack of {name: raw} in table order."""
        return self._image

    def crc(self) -> int:
        return self._crc

    def stored_image(self, logbook: dict[str, int]) -> bytes:
        """The set with the engine's logbook as a save puts it in flash: the parameters (as
        :meth:`image`) and the logbook's words under ``ecu.logbook.STORE_KEY``."""
        return msgpack.packb({**self._raws, STORE_KEY: logbook})

    def load_image(self, image: bytes) -> list[str]:
        """Apply a stored set (entry by entry, limits checked, the whole set validated at the
        end); returns the problems found, each naming the parameter. Bad entries are skipped."""
        problems: list[str] = []
        try:
            stored = msgpack.unpackb(image)
        except (ValueError, TypeError, msgpack.UnpackException) as exc:
            return [f"stored set unreadable: {exc}"]
        if not isinstance(stored, dict):
            return ["stored set is not a map of names to values"]
        params = self.params
        for name, raw in stored.items():
            if name == STORE_KEY:
                continue  # the engine's logbook (stored_logbook), not a parameter
            spec = BY_NAME.get(name) if isinstance(name, str) else None
            if spec is None:
                problems.append(f"{name!r}: not a parameter of this firmware, skipped")
            elif not isinstance(raw, int) or not spec.raw_lo <= raw <= spec.raw_hi:
                problems.append(f"{name}: stored value {raw!r} outside its limits, skipped")
            else:
                params = _with(params, spec, spec.to_value(raw))
        try:
            self.commit(params, compile_params(params))
        except (ValueError, ArithmeticError) as exc:
            problems.append(f"stored set refused by the parameter checks, defaults kept: {exc}")
        return problems


def stored_logbook(image: bytes) -> dict | None:
    """The engine's logbook of a stored set ({word name: value}), None when the set has none
    (an image saved before the logbook) or cannot be read."""
    try:
        stored = msgpack.unpackb(image)
    except (ValueError, TypeError, msgpack.UnpackException):
        return None
    logbook = stored.get(STORE_KEY) if isinstance(stored, dict) else None
    return logbook if isinstance(logbook, dict) else None
