"""The C XCP slave's run record: what it needs to know of one run's parameter set to check and
apply a calibration write on the target, in integers, as :mod:`ecu.service.param_table` and
:func:`ecu.firmware_params.compile_params` do in Python.

A write of a parameter (its raw Q integer, ``ParamSpec.to_raw``) must update the firmware
constants compiled from it. On the target that is done without floating point:

- an *identity* parameter is its firmware word (``trim_v`` is ``trim_v_q24``): the word is the
  raw value (:data:`IDENTITY`);
- a *recipe* recomputes a firmware word from the raw value as ``compile_params`` does, the same
  IEEE double operations in the same order (a product or quotient by a constant of the run:
  ``dt``, 10.0, ``p22 * dt``, ...) then ``round`` (half to even) at the word's Q format, optionally
  at least 1 (``ticks``); the C slave does these double operations exactly in integers
  (correctly rounded, as IEEE 754 does them), so its words are ``compile_params``' bit for bit
  (:data:`RECIPES`, :func:`recipes`, the constants of :func:`pool`);
- a few words of several parameters are *derived* by the C slave's own code after every write
  (``pump_v0_q24``, ``lam_comm_v0_q16``, the K_b start value, the start's EGT cap and day
  target, the inlet correction, the starter ramp step): :data:`DERIVED_INPUTS`;
- the parameters whose words need the PI design, the Tustin discretisation, ``exp`` or a
  division by another parameter (:data:`COMMISSIONING`) are not written by the C slave: it
  refuses them with ERR_WRITE_PROTECTED (the calibration block of the image, or the C node's
  parameters at start-up, set them).

The whole-set checks of :func:`ecu.params.validate` that concern the parameters the C slave
writes are kept: the cross-parameter rules (generated into C from :data:`RULES` by
:mod:`ecu.port.xcp_map`) and, for a rule with a parameter outside the table (``p22``,
``flameout_margin``, ``egt_open_high_k``, ...), the raw bounds it puts on one parameter in this
run (:func:`bounds`, found by bisection over the rule as Python evaluates it).

The record is a list of int32 words (layout: the ``RUN_*`` offsets below, written into the
generated header), given to the C slave at start-up (the C node's configuration, or the image's
calibration block).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, replace

from ecu.firmware_params import FirmwareParams, compile_params
from ecu.params import N_MAX_RPM, READING_B0, EcuParams, ParamError, firmware_convention
from ecu.port.core import param_words
from ecu.service.param_table import TABLE, ParamTable
from ecu.service.port import FIRMWARE, build_id

INDEX = {spec.name: k for k, spec in enumerate(TABLE)}

# the constants of the run a recipe multiplies or divides by (IEEE doubles), by slot
POOL = (
    "DT", "GPDT", "B0", "TEN", "HUNDRED", "K256", "THOUSAND", "TEN_THOUSAND", "RPM", "HZ",
    "MARGIN", "KBQ", "INV_P22",
)  # fmt: skip
POOL_SLOTS = 16
P = {name: k for k, name in enumerate(POOL)}
MUL, DIV = 1, 2  # a recipe's operations: (kind, pool slot)

# parameter -> its firmware word (the raw value is the word)
IDENTITY: dict[str, str] = {
    "pid_kp": "pid_kp_q24",
    "pid_kd": "pid_kd_q24",
    "egt_kp": "egt_kp_q24",
    "accel_max_pct_s": "accel_max_q24",
    "decel_max_pct_s": "decel_max_q24",
    "adapt_band_pct": "adapt_band_q24",
    "trim_n_pct": "trim_n_q24",
    "trim_v": "trim_v_q24",
    "entry_v": "entry_v_q24",
    "idle_pct": "idle_q24",
    "demand_max_pct": "demand_max_q24",
    "n_limit_pct": "n_limit_q24",
    "v_min": "v_min_q24",
    "v_max": "v_max_q24",
    "lambda_commissioned": "lambda_comm_q24",
    "pump_dead_v": "pump_dead_q24",
    "pump_scaling_on": "pump_scaling_on",
    "limiters_on": "limiters_on",
    "rate_filter_on": "rate_filter_on",
    "fuel_schedules_on": "fuel_schedules_on",
    "inlet_from_egt": "inlet_from_egt",
    "start_on": "start_on",
    "start_ign_v0": "seq_ign_v0_q24",
    "start_ign_v_max": "seq_ign_v_max_q24",
    "start_accel_pct_s": "seq_accel_q24",
    "relight_max": "seq_relight_max",
    **{f"accel_line_v[{k}]": f"accel_line_q24[{k}]" for k in range(12)},
    **{f"decel_floor_v[{k}]": f"decel_floor_q24[{k}]" for k in range(12)},
    **{f"accel_rate_pct_s[{k}]": f"accel_rate_q24[{k}]" for k in range(12)},
}


@dataclass(frozen=True)
class Recipe:
    """``word`` = round(raw * 2**-frac, then each (kind, slot) of ``ops``, * 2**k) half to
    even; at least 1 with ``at_least_1``."""

    param: str
    word: str
    ops: tuple[tuple[int, int], ...]
    k: int
    at_least_1: bool = False


def _r(param: str, word: str, ops: tuple[str, ...], k: int = 0, at_least_1: bool = False):  # noqa: ANN202
    parsed = tuple((DIV, P[o[1:]]) if o.startswith("/") else (MUL, P[o]) for o in ops)
    return Recipe(param, word, parsed, k, at_least_1)


_TICKS = {
    "start_purge_s": "seq_purge_ticks",
    "start_spinup_timeout_s": "seq_spinup_ticks",
    "start_ignition_timeout_s": "seq_ign_ticks",
    "start_igniter_hold_s": "seq_igniter_hold_ticks",
    "start_ramp_timeout_s": "seq_ramp_ticks",
    "start_stabilise_timeout_s": "seq_stabilise_ticks",
    "cool_soak_s": "seq_soak_ticks",
    "cool_timeout_s": "seq_cool_ticks",
    "flameout_egt_time_s": "flameout_egt_ticks",
}
_RPM = {
    "overspeed_pct": "overspeed_rpm",
    "start_ignition_pct": "seq_ign_rpm",
    "start_cutoff_pct": "seq_cutoff_rpm",
    "start_idle_pct": "seq_idle_rpm",
    "cool_speed_pct": "seq_cool_rpm",
}
_DK = {
    "egt_limit_k": "egt_limit_dk",
    "egt_max_k": "egt_max_dk",
    "egt_gas_margin_k": "egt_gas_margin_dk",
    "egt_zero_fuel_k": "egt_zero_fuel_dk",
    "start_light_rise_k": "seq_light_rise_dk",
    "start_egt_target_k": "seq_egt_target_dk",
    "start_egt_limit_k": "seq_hot_dk",
    "cool_egt_k": "seq_cool_egt_dk",
    "cool_rearm_k": "seq_cool_rearm_dk",
    "flameout_egt_k": "flameout_egt_dk",
}
_CPCT = {"duty_max": "duty_max_cpct", "start_duty": "seq_start_cpct", "cool_duty": "seq_cool_cpct"}
_DT = {
    "egt_ki": ("egt_ki_dt_q24", 24),
    "v_slew_v_s": ("v_slew_q24", 24),
    "start_ign_v_rate": ("seq_ign_v_step_q24", 24),
    "start_ramp_v_rate": ("seq_ramp_v_step_q24", 24),
    "pid_ki": ("pid_ki_dt_q28", 28),
}

# compile_params' expressions for the parameters the C slave writes, in the printed reading
# (RECIPES_REPRODUCING: what the reproducing reading changes, firmware_convention)
RECIPES: tuple[Recipe, ...] = (
    *(_r(n, w, ("DT",), k) for n, (w, k) in _DT.items()),
    *(_r(f"gamma_x[{i}]", f"g_x{i + 1}_q28", ("B0", "DT"), 28) for i in range(2)),
    _r("gamma_r", "g_r_q28", ("B0", "DT"), 28),
    *(_r(f"gamma_f[{i}]", f"g_f{i + 1}_q28", ("B0", "DT"), 28) for i in range(2)),
    *(_r(f"gamma_a[{i}]", f"g_a{i + 1}_q28", ("GPDT",), 28) for i in range(2)),
    _r("gamma_lambda", "g_lam_q28", ("B0", "B0", "GPDT"), 28),
    *(_r(f"gamma_theta[{i}]", f"g_th{i + 1}_q28", ("GPDT",), 28) for i in range(2)),
    _r("gamma_b", "g_b_q28", ("B0", "DT"), 28),
    _r("p12", "p12_ratio_q24", ("INV_P22",), 24),
    _r("pump_health_alarm", "health_alarm_pm", ("THOUSAND",)),
    _r("idle_pct", "flameout_rpm", ("MARGIN", "RPM", "/HUNDRED")),
    *(_r(n, w, ("TEN",)) for n, w in _DK.items()),
    *(_r(n, w, ("TEN_THOUSAND",)) for n, w in _CPCT.items()),
    *(_r(n, w, ("RPM", "/HUNDRED")) for n, w in _RPM.items()),
    *(_r(n, w, ("HZ",), 0, True) for n, w in _TICKS.items()),
    _r("start_light_track_k_s", "seq_light_track_q8", ("TEN", "K256", "DT"), 0, True),
)
# the reproducing reading: Theta_f and K_f pair the other way round (firmware_convention)
SWAPPED = {"gamma_f[0]": "g_f2_q28", "gamma_f[1]": "g_f1_q28",
           "gamma_theta[0]": "g_th2_q28", "gamma_theta[1]": "g_th1_q28"}  # fmt: skip

# words the C slave derives from several parameters after a write (ecu_xcp.c derive())
DERIVED_INPUTS = (
    "trim_v", "pump_dead_v", "inlet_temp_k", "start_duty", "start_starter_ramp_s",
    "start_egt_target_k", "start_egt_limit_k", "start_egt_margin_k",
)  # fmt: skip
DERIVED_WORDS = (
    "pump_v0_q24", "lam_comm_v0_q16", "init_theta_q24[11]", "seq_egt_cap_dk",
    "seq_day_target_dk", "ncor_k_q24", "seq_starter_step_cpct",
)  # fmt: skip

# words of design and model steps the target does not compute: these parameters are set with
# the calibration (the image's block, the C node's parameters), not written over XCP on C
COMMISSIONING = (
    "trim_n_pct",  # the PI schedule (ecu.pi_design: tan, hypot, phase)
    "lambda_commissioned",  # divisions: Theta_f per Lambda, the schedules' pump range, K_b
    "pump_scaling_on",  # Theta_f-hat's scale Lambda-hat / Lambda_c and K_b
    "ref_wn", "ref_zeta",  # the reference model's Tustin discretisation
    "mrac_cmd_lag_s", "egt_lead_tau_s", "egt_lead_filter_s",  # dt / (T + dt)
    "rate_filter_bw",  # exp(-bw dt)
)  # fmt: skip

# cross-parameter rules of ecu.params.validate among the parameters the C slave writes
# (generated into C): (kind, a, b, c) with raws A, B, C; a broken one refuses with ERR_VERIFY
LT, LE, LE_OFF, SUM_LE, ZERO_OR_RANGE, GE_MUL, NONDECREASING, BELOW = range(8)
RULES: tuple[tuple, ...] = (
    (LE, "v_min", "trim_v"), (LE, "trim_v", "v_max"), (LE, "v_min", "entry_v"),
    (LE, "entry_v", "v_max"), (LT, "pump_dead_v", "trim_v"), (LT, "idle_pct", "demand_max_pct"),
    (LT, "demand_max_pct", "n_limit_pct"), (LT, "n_limit_pct", "overspeed_pct"),
    (LT, "egt_limit_k", "egt_max_k"),
    (SUM_LE, "egt_gas_margin_k", "egt_limit_k", "egt_max_k"),  # margin <= max - limit
    (ZERO_OR_RANGE, "egt_zero_fuel_k", "egt_limit_k", 150.0, 300.0),  # 0, or 150..limit-300
    (LT, "v_min", "v_max"),
    (LT, "start_ignition_pct", "start_cutoff_pct"), (LT, "start_cutoff_pct", "start_idle_pct"),
    (GE_MUL, "start_idle_pct", "idle_pct", "MARGIN"),  # >= idle (1 - flameout_margin)
    (LT, "start_ign_v0", "start_ign_v_max"), (LE, "start_ign_v_max", "v_max"),
    (LT, "start_egt_target_k", "start_egt_limit_k"), (LE, "start_egt_limit_k", "egt_max_k"),
    (LE_OFF, "start_egt_margin_k", "start_egt_limit_k", 400.0),  # margin <= limit - 400 K
    (LT, "start_purge_s", "start_spinup_timeout_s"),
    (NONDECREASING, "accel_line_v[0]"), (NONDECREASING, "decel_floor_v[0]"),
    (BELOW, "decel_floor_v[0]", "accel_line_v[0]"),  # at every breakpoint
)  # fmt: skip

# the run record: int32 words
ID_LEN = len(f"{FIRMWARE} build ") + 12
STORED = tuple(spec.name for spec in TABLE if spec.name not in IDENTITY)
MAX_RECIPES = 64
MAX_BOUNDS = 16
RUN_ID = 0  # the identification (GET_ID type 0, the A2L's EPK), ASCII, little-endian words
RUN_STORED = RUN_ID + (ID_LEN + 3) // 4  # the raws of the parameters that are no word
RUN_POOL = RUN_STORED + len(STORED)  # POOL_SLOTS doubles, low word first
RUN_WRITABLE = RUN_POOL + 2 * POOL_SLOTS  # a bit per parameter: the C slave writes it
RUN_BOUNDS = RUN_WRITABLE + (len(TABLE) + 31) // 32  # (param, lo, hi) * MAX_BOUNDS, param -1: end
RUN_RECIPES = RUN_BOUNDS + 3 * MAX_BOUNDS  # a count, then (head, ops) * MAX_RECIPES
RUN_WORDS = RUN_RECIPES + 1 + 2 * MAX_RECIPES


class RunRecordError(ValueError):
    """The run's parameters do not fit the C slave's record."""


def _bits(x: float) -> tuple[int, int]:
    (u,) = struct.unpack("<Q", struct.pack("<d", x))
    lo, hi = u & 0xFFFF_FFFF, u >> 32
    return lo - (1 << 32) if lo >= 1 << 31 else lo, hi - (1 << 32) if hi >= 1 << 31 else hi


def _power_of_two(x: float) -> bool:
    m, _ = math.frexp(x)
    return x > 0 and m == 0.5


def pool(p: EcuParams) -> dict[str, float]:
    """The run's constants, each the double compile_params computes it as."""
    q = firmware_convention(p)
    dt = 1.0 / p.rate_hz
    kbq = p.lambda_commissioned / p.init_lambda - 1.0 if p.pump_scaling_on else 0.0
    return {
        "DT": dt,
        "GPDT": q.p22 * dt,
        "B0": READING_B0 if p.reading == "reproducing" else 1.0,
        "TEN": 10.0,
        "HUNDRED": 100.0,
        "K256": 256.0,
        "THOUSAND": 1000.0,
        "TEN_THOUSAND": 10000.0,
        "RPM": float(N_MAX_RPM),
        "HZ": float(p.rate_hz),
        "MARGIN": 1.0 - p.flameout_margin,
        "KBQ": kbq,
        "INV_P22": 1.0 / q.p22 if _power_of_two(q.p22) else 0.0,
    }


def writable(p: EcuParams) -> set[str]:
    """The parameters the C slave writes in this run."""
    out = {spec.name for spec in TABLE} - set(COMMISSIONING)
    if not _power_of_two(firmware_convention(p).p22):
        out.discard("p12")  # p12 / p22 is a division
    return out


def recipes(p: EcuParams) -> list[Recipe]:
    """The recipes of this run (the reading decides which word a Theta_f or K_f gain feeds)."""
    allowed = writable(p)
    out = []
    for r in RECIPES:
        if r.param not in allowed:
            continue
        if p.reading == "reproducing" and r.param in SWAPPED:
            r = replace(r, word=SWAPPED[r.param])
        out.append(r)
    return out


def _largest(ok: Callable[[int], bool], lo: int, hi: int) -> int:
    """The largest raw in lo..hi with ok (ok monotone: true up to a point), lo - 1 if none."""
    if not ok(lo):
        return lo - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        lo, hi = (mid, hi) if ok(mid) else (lo, mid - 1)
    return lo


def bounds(p: EcuParams) -> list[tuple[str, int, int]]:
    """Raw bounds (inclusive) that ecu.params.validate puts on one parameter in this run, through
    a rule with values outside the table: (name, lo, hi), within the parameter's limits."""
    q = firmware_convention(p)
    dt = 1.0 / p.rate_hz
    out = []
    allowed = writable(p)

    def bound(name: str, ok_hi: Callable[[float], bool] | None = None,
              ok_lo: Callable[[float], bool] | None = None) -> None:  # fmt: skip
        spec = TABLE[INDEX[name]]
        if name not in allowed:
            return
        lo, hi = spec.raw_lo, spec.raw_hi
        if ok_hi is not None:
            hi = _largest(lambda r: ok_hi(spec.to_value(r)), lo, hi)
        if ok_lo is not None:
            lo = -_largest(lambda r: ok_lo(spec.to_value(-r)), -hi, -lo)
        if (lo, hi) != (spec.raw_lo, spec.raw_hi):  # tighter than the limits
            out.append((name, lo, hi))

    b0 = READING_B0 if p.reading == "reproducing" else 1.0
    gains = (
        "gamma_a[0]", "gamma_a[1]", "gamma_theta[0]", "gamma_theta[1]", "gamma_x[0]",
        "gamma_x[1]", "gamma_f[0]", "gamma_f[1]", "gamma_r", "gamma_b", "gamma_lambda",
    )  # fmt: skip
    for name in gains:
        scale = 1.0 if name.startswith(("gamma_a", "gamma_theta")) else b0

        def gain_ok(g: float, scale: float = scale, lam: bool = name == "gamma_lambda") -> bool:
            converted = g * scale * scale if lam else g * scale
            return g * p.p22 * dt < 4.0 and converted * q.p22 * dt < 4.0

        bound(name, gain_ok)
    bound("p12", lambda x: x <= -p.am_row2[1] * p.p22)
    bound("idle_pct", lambda x: p.run_entry_pct >= x * (1.0 - p.flameout_margin))
    bound("egt_max_k", lambda x: x < p.egt_open_high_k)
    bound("v_min", lambda x: p.supply_nominal_v > x)
    bound("duty_max", ok_lo=lambda x: p.duty_min < x)
    if len(out) > MAX_BOUNDS:
        raise RunRecordError(f"{len(out)} bounds: the record holds {MAX_BOUNDS}")
    return out


def _word_index() -> dict[str, int]:
    """FirmwareParams word name (``name`` or ``name[k]``) -> its index in the words."""
    out, at = {}, 0
    words = param_words(compile_params(EcuParams()))
    p = compile_params(EcuParams())
    for name in FirmwareParams.FIELDS:
        value = getattr(p, name)
        if isinstance(value, tuple):
            for k in range(len(value)):
                out[f"{name}[{k}]"] = at
                at += 1
        else:
            out[name] = at
            at += 1
    assert at == len(words)
    return out


WORD = _word_index()


def run_record(table: ParamTable) -> list[int]:
    """The run record of the set ``table`` holds (its raws, the run's constants, recipes and
    bounds), as int32 words."""
    p = table.params
    try:
        compile_params(p)
    except ParamError as exc:
        raise RunRecordError(str(exc)) from None
    words = [0] * RUN_WORDS
    ident = f"{FIRMWARE} build {build_id()}".encode("ascii")
    if len(ident) != ID_LEN:
        raise RunRecordError(f"identification {ident!r}: {ID_LEN} characters expected")
    for k in range(0, ID_LEN, 4):
        words[RUN_ID + k // 4] = struct.unpack("<i", ident[k : k + 4].ljust(4, b"\0"))[0]
    raws = dict(zip((s.name for s in TABLE), table.raws(), strict=True))
    for k, name in enumerate(STORED):
        words[RUN_STORED + k] = raws[name]
    for name, value in pool(p).items():
        words[RUN_POOL + 2 * P[name]], words[RUN_POOL + 2 * P[name] + 1] = _bits(value)
    allowed = writable(p)
    for k, spec in enumerate(TABLE):
        if spec.name in allowed:
            words[RUN_WRITABLE + k // 32] |= 1 << (k % 32)
    for k in range(RUN_WRITABLE, RUN_BOUNDS):
        if words[k] >= 1 << 31:
            words[k] -= 1 << 32
    found = bounds(p)
    for k in range(MAX_BOUNDS):
        name, lo, hi = found[k] if k < len(found) else (None, 0, 0)
        at = RUN_BOUNDS + 3 * k
        words[at : at + 3] = [INDEX[name] if name else -1, lo, hi]
    chosen = recipes(p)
    if len(chosen) > MAX_RECIPES:
        raise RunRecordError(f"{len(chosen)} recipes: the record holds {MAX_RECIPES}")
    words[RUN_RECIPES] = len(chosen)
    for k, r in enumerate(chosen):
        spec = TABLE[INDEX[r.param]]
        ops = 0
        for j, (kind, slot) in enumerate(r.ops):
            ops |= (kind << 4 | slot) << (6 * j)
        head = INDEX[r.param] | WORD[r.word] << 8 | (r.k & 0xFF) << 16
        head |= (spec.frac_bits | (32 if r.at_least_1 else 0)) << 24
        words[RUN_RECIPES + 1 + 2 * k] = head
        words[RUN_RECIPES + 2 + 2 * k] = ops
    return words
