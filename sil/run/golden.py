"""Golden vectors for the C port (format: :mod:`ecu.golden`), recorded from the Python firmware
in closed loop.

Sources:
- SIL scenarios run in one process (command node, ECU, plant as in ``sil run --mode inproc``),
  cut to their first ticks: MRAC, PID and open loop on the aero-thermal plant, plant and sensor
  faults, limit loops on a hot day, the transients from idle and from maximum (an entry voltage
  other than the trim's);
- a scripted sequence for what the SIL never does (it arms once and runs): OFF, ARMED, RUN,
  SHUTDOWN and a latched FAULT, lost and corrupt frames, pump current faults;
- a scripted start and stop through the start/stop sequencer (ecu.start_sequencer): starts
  from rest, relights, stops with their cool-downs, every abort;
- the bench test functions (ecu.actuator_tests) at rest, their refusals and ends, then a start.

    python -m sil.run.golden OUT_DIR [NAME ...] [--ticks N]   write the vectors (all: no NAME)
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from ecu import modes
from ecu import start_sequencer as seq
from ecu.firmware import E2E_NONEWDATA, E2E_OK, E2E_WRONGCRC, EcuInputs, EcuOutputs
from ecu.firmware_params import compile_params
from ecu.golden import Golden, RecordingEcu, write
from ecu.node import EcuNode
from ecu.params import EcuParams
from plant.fast_model import FastEngine
from plant.node import PlantNode
from protocol.codec import Codec
from protocol.node import InProcessBus
from sil import scenario
from sil.record.recorder import Recorder
from sil.run import runner
from sil.run.command_node import CommandNode
from sil.scenario import profiles


def record_scenario(name: str, scenario_text: str, ticks: int) -> Golden:
    """Run a scenario (TOML text or a shipped name) in process for ``ticks`` ticks, recording."""
    if "\n" in scenario_text:
        s = scenario.parse(scenario_text, name, Path("."))
    else:
        s = scenario.load(scenario_text)
    s = dataclasses.replace(s, duration_s=ticks / s.ecu_rate_hz)
    plant = runner.build_plant(s, s.seed)
    ecu_params = runner.ecu_params(s, plant)
    params = compile_params(ecu_params)
    open_loop = s.controller.kind == "open_loop"
    trim_value = plant.trim_pump_voltage if open_loop else ecu_params.trim_n_pct
    commands = profiles.sample(s.profile(trim_value), s.duration_s, s.ecu_rate_hz)
    ecu = RecordingEcu(params)
    codec = Codec()
    with tempfile.TemporaryDirectory() as tmp:
        recorder = Recorder(Path(tmp), codec, 1.0 / s.ecu_rate_hz, commands=commands)
        command = CommandNode(
            codec,
            recorder,
            commands,
            ecu_rate_hz=s.ecu_rate_hz,
            open_loop=open_loop,
            faults=s.faults,
        )
        node = EcuNode(ecu=ecu)
        InProcessBus([command, node, PlantNode(plant)]).run(done=lambda: command.finished)
        recorder.close()
    return Golden(name, params, ecu.rows)


def record_modes(ticks: int) -> Golden:
    """Scripted inputs through every mode, with lost and corrupt frames and a pump fault.

    One phase per 100 ticks: OFF; arm, the starter spools up (ARMED), RUN; demand frames lost
    (hold, idle), corrupt and missing sensor frames; analog frames lost; stop (SHUTDOWN), spool
    down, disarm (OFF); arm again, supply sag, EGT thermocouple open; demand lost past the
    shutdown time; disarm, re-arm; a stalled pump (FAULT, latched). Speed follows the eq. 3.24
    fast model while the ECU runs. Without the start sequencer (``start_on`` off: ARMED waits
    for an external starter, SHUTDOWN has no cool-down); the sequencer's modes are
    :func:`record_start_stop`'s.
    """
    p = EcuParams(start_on=False)
    ecu = RecordingEcu(p)
    engine = FastEngine()
    i = EcuInputs()
    n_pct = 5.0
    dt = 1.0 / p.rate_hz
    for k in range(ticks):
        phase, j = divmod(k, 100)
        arm = 0 if phase in (0, 6, 7, 8, 15, 16) else 1
        stop = 1 if phase == 5 else 0
        mode = ecu.out.mode
        if mode == modes.RUN:
            engine.step(ecu.out.pump_mv / 1000.0 - p.trim_v, dt)
            n_pct = engine.n_pct
        elif mode == modes.ARMED or (mode == modes.OFF and arm and not stop):
            n_pct += (engine.trim_n_pct - n_pct) * dt / 0.8  # the starter brings it up
            engine.dn_pct, engine.dn_dot = n_pct - engine.trim_n_pct, 0.0
        else:
            n_pct -= n_pct * dt / 0.6  # spool down
        i.tick = k % 65536
        i.speed_rpm = max(0, round(n_pct * 1125.0) + (k * 7919) % 41 - 20)  # with noise
        i.egt_dk = max(2900, 10480 + round(200 * (n_pct - 89.68)))  # ambient when cold
        if phase == 11 and j >= 50:
            i.egt_dk = 0  # thermocouple open, reading low: EGT_OPEN, demand limited
        i.supply_mv = 22200 - (3000 if phase == 11 else 0)
        i.pump_ma = (1050 + 60 * ecu.out.pump_mv // 1000) if ecu.out.pump_enable else 0
        if phase >= 19:
            i.pump_ma = 6000  # seized pump: over current
        i.demand_cpct = 8968 + (300 if phase % 2 else -200)
        i.open_loop_mv = 0
        i.arm, i.stop = arm, stop
        i.sensor_status = E2E_OK
        i.analog_status = E2E_OK if k % 5 == 0 else E2E_NONEWDATA
        i.demand_status = E2E_OK if k % 5 == 0 else E2E_NONEWDATA
        if phase == 3:  # demand frames lost for a second, some sensor frames corrupt
            i.demand_status = E2E_NONEWDATA
            if j % 7 == 3:
                i.sensor_status = E2E_WRONGCRC
            elif j % 11 == 5:
                i.sensor_status = E2E_NONEWDATA
        if phase == 4 and j < 60:
            i.analog_status = E2E_NONEWDATA  # analog lost: nominal supply assumed
        if phase in (12, 13, 14):
            i.demand_status = E2E_NONEWDATA  # demand lost beyond the shutdown time
        ecu.tick(i)
    return Golden("modes", compile_params(p), ecu.rows)


# the sequencer's timeouts cut from seconds to tenths (the sequence in a few thousand ticks);
# its speeds and temperatures pinned for StartEngine (whatever the defaults' tuning)
START_STOP_PARAMS = EcuParams(
    start_duty=0.5,
    start_purge_s=0.3,
    start_ignition_pct=4.0,
    start_spinup_timeout_s=0.8,
    start_ign_v0=1.5,
    start_ign_v_rate=2.0,
    start_ign_v_max=3.0,
    start_light_rise_k=30.0,
    start_light_track_k_s=20.0,
    start_ignition_timeout_s=0.6,
    start_igniter_hold_s=0.2,
    start_starter_ramp_s=0.3,
    start_ramp_v_rate=5.0,
    start_accel_pct_s=20.0,
    start_egt_target_k=1100.0,
    start_egt_limit_k=1200.0,
    start_cutoff_pct=36.0,
    start_ramp_timeout_s=1.5,
    start_idle_pct=40.0,
    start_stabilise_timeout_s=1.0,
    relight_max=1,
    cool_duty=0.6,
    cool_egt_k=363.0,
    cool_rearm_k=10.0,
    cool_speed_pct=40.0,
    cool_timeout_s=0.5,
    cool_soak_s=0.5,
    flameout_time_s=0.3,
    flameout_egt_k=420.0,
    flameout_egt_time_s=0.3,
)
AMBIENT_K = 290.0


class StartEngine:
    """A toy engine for the scripted start and stop (%N, K), driven by the ECU's outputs.

    The starter drives the rotor towards 45 %N x duty; lit (the igniter on, with fuel and the
    rotor turning, for 0.15 s), the fuel drives it towards 40 %N at 3 V plus 5.28 %N/V (a line
    through the trim point, 89.68 %N at 12.41 V) and the gas towards 600 K + 36 K/V; unlit, the
    gas goes to ambient plus ``soak_k`` (the hot section's heat soaking back, as the script sets
    it), fast with airflow, slowly in still air. Failures: ``starter_ok`` (the starter turns
    nothing), ``ignites`` (no light-off), ``hot_k`` (a hot start), ``weak_pct`` (a hung start).
    """

    def __init__(self) -> None:
        self.n_pct = 0.0
        self.egt_k = AMBIENT_K
        self.lit = False
        self.sparks = 0
        self.starter_ok = True
        self.ignites = True
        self.hot_k = 0.0
        self.weak_pct = 0.0
        self.soak_k = 0.0

    def flame_out(self) -> None:
        self.lit = False
        self.sparks = 0

    def step(self, o: EcuOutputs, dt: float) -> None:
        v = o.pump_mv / 1000.0 if o.pump_enable else 0.0
        duty = o.starter_cpct / 10000.0 if self.starter_ok else 0.0
        if v < 0.5:
            self.flame_out()
        elif not self.lit and self.ignites and o.igniter and self.n_pct > 3.0:
            self.sparks += 1
            self.lit = self.sparks >= 15
        target = 45.0 * duty
        if self.lit:
            target = max(target, 40.0 + 5.28 * (v - 3.0) - self.weak_pct)
        self.n_pct += (target - self.n_pct) * dt / (0.4 if target > self.n_pct else 0.8)
        if self.lit:
            gas, tau = 600.0 + 36.0 * v + self.hot_k, 0.25
        else:
            gas, tau = AMBIENT_K + self.soak_k, 1.0 - 0.75 * min(1.0, self.n_pct / 20.0)
        self.egt_k += (gas - self.egt_k) * dt / tau


def _start_stop_script(o: EcuOutputs, engine: StartEngine, cmd: dict[str, int]) -> Iterator[None]:
    """One yield per tick: sets the arm and stop requests in ``cmd`` and the engine's failures,
    waiting on the ECU's outputs ``o``; raises if the ECU does not get where the step expects."""

    def hold(ticks: int, **request: int) -> Iterator[None]:
        cmd.update(request)
        for _ in range(ticks):
            yield

    def until(done: Callable[[], bool], limit: int = 400, **request: int) -> Iterator[None]:
        cmd.update(request)
        for _ in range(limit):
            if done():
                return
            yield
        raise RuntimeError(
            f"scripted start/stop: mode {modes.NAMES[o.mode]}, sequencer "
            f"{seq.NAMES[o.seq_state]} ({seq.REASONS[o.seq_reason]}) after {limit} ticks"
        )

    def is_mode(mode: int) -> Callable[[], bool]:
        return lambda: o.mode == mode

    def is_state(state: int) -> Callable[[], bool]:
        return lambda: o.seq_state == state

    def aborted(reason: int) -> Callable[[], bool]:
        return lambda: o.seq_reason == reason

    def still_off(why: str) -> None:
        if o.mode != modes.OFF:
            raise RuntimeError(f"scripted start/stop: {why}, yet mode {modes.NAMES[o.mode]}")

    # power-up with no sensor frame yet, the arm held: no readings, no speed, the arm refused
    yield from hold(20, arm=1, stop=0, sensors=0)
    still_off("armed before any sensor reading")
    yield from hold(10, arm=0, sensors=1)
    # the starter turns nothing: STARTER_FAILURE, SHUTDOWN (DONE at once: cold), OFF
    engine.starter_ok = False
    yield from until(aborted(seq.STARTER_FAILURE), arm=1)
    yield from until(is_mode(modes.OFF), arm=0)
    engine.starter_ok = True
    # stopped in the spin-up with the arm held (STOPPED, OFF at once); the stop released with the
    # arm still held: no new start until the arm is released
    yield from until(is_state(seq.SPIN_UP), arm=1)
    yield from hold(5)
    yield from until(is_mode(modes.OFF), stop=1)
    yield from hold(20, stop=0)
    still_off("a stopped start retried by itself")
    # no demand frames: the arm refused
    yield from hold(30, arm=0)
    yield from hold(30, arm=1, demand=0)
    still_off("armed without a demand")
    # from rest: SPIN_UP, IGNITION, RAMP, STABILISE, RUN at 45 %N
    yield from until(is_mode(modes.RUN), arm=1, demand=1)
    yield from hold(40)
    # a flameout in RUN: relight (ARMED, IGNITION with the rotor still turning), RUN again
    engine.flame_out()
    yield from until(is_mode(modes.ARMED))
    yield from until(is_mode(modes.RUN))
    yield from hold(40)
    # stop: SHUTDOWN, SPOOL_DOWN, COOL_DOWN, DONE; the heat soaks back: COOL_DOWN, DONE; OFF
    yield from until(is_state(seq.DONE), stop=1, arm=0)
    engine.soak_k = 150.0
    yield from until(is_state(seq.COOL_DOWN))
    engine.soak_k = 0.0
    yield from until(is_mode(modes.OFF))
    yield from hold(5, stop=0)
    # no light-off: IGNITION_TIMEOUT, SHUTDOWN, OFF
    engine.ignites = False
    yield from until(aborted(seq.IGNITION_TIMEOUT), arm=1)
    yield from until(is_mode(modes.OFF), arm=0)
    engine.ignites = True
    # released in the spin-up (STOPPED, OFF at once), stopped in the ignition (SHUTDOWN)
    yield from until(is_state(seq.SPIN_UP), arm=1)
    yield from hold(10)
    yield from until(is_mode(modes.OFF), arm=0)
    yield from until(is_state(seq.IGNITION), arm=1)
    yield from hold(5)
    yield from until(is_mode(modes.SHUTDOWN), stop=1)
    yield from until(is_mode(modes.OFF), stop=0, arm=0)
    # a hot start: HOT_START; too hot to cool under cool_egt, the cool-down times out
    engine.hot_k = 600.0
    yield from until(aborted(seq.HOT_START), arm=1)
    engine.hot_k = 0.0
    engine.soak_k = 100.0
    yield from until(is_state(seq.COOL_DOWN))
    yield from until(is_state(seq.DONE))
    engine.soak_k = 0.0
    yield from until(is_mode(modes.OFF), arm=0)
    # a hung start: SLOW_ACCEL
    engine.weak_pct = 15.0
    yield from until(aborted(seq.SLOW_ACCEL), arm=1)
    yield from until(is_mode(modes.OFF), arm=0)
    engine.weak_pct = 0.0
    # the flame goes out just after light-off: FLAMEOUT
    yield from until(is_state(seq.RAMP), arm=1)
    yield from hold(2)
    engine.flame_out()
    engine.ignites = False
    yield from until(aborted(seq.FLAMEOUT))
    yield from until(is_mode(modes.OFF), arm=0)
    engine.ignites = True
    # a start, then two flameouts in RUN: one relight (relight_max), then SHUTDOWN
    yield from until(is_mode(modes.RUN), arm=1)
    yield from hold(20)
    engine.flame_out()
    yield from until(is_mode(modes.ARMED))
    yield from until(is_mode(modes.RUN))
    yield from hold(20)
    engine.flame_out()  # the gas held warm: found by the speed (the first two, by the EGT)
    engine.ignites = False
    engine.soak_k = 200.0
    yield from until(is_mode(modes.SHUTDOWN))
    engine.soak_k = 0.0
    yield from until(is_mode(modes.OFF), arm=0)
    while True:  # OFF from here on
        yield


def record_start_stop(ticks: int) -> Golden:
    """Scripted starts and stops through the start/stop sequencer, on :class:`StartEngine`
    (the sequencer's timeouts cut short: START_STOP_PARAMS).

    Power-up with no sensor frames (the arm refused); the starter fails (STARTER_FAILURE); a
    start stopped with the arm held, not retried; the arm refused without demand frames; a start
    from rest through SPIN_UP, IGNITION, RAMP,
    STABILISE to RUN; a flameout in RUN and its relight; a stop through SPOOL_DOWN, COOL_DOWN,
    DONE, a heat soak-back (COOL_DOWN again) and OFF; no light-off (IGNITION_TIMEOUT); released
    in the spin-up and stopped in the ignition (STOPPED); a hot start (HOT_START) whose
    cool-down times out; a hung start (SLOW_ACCEL); the flame lost after light-off (FLAMEOUT);
    a second flameout in RUN with no relight left (SHUTDOWN). About 2,500 ticks, OFF after.
    """
    p = START_STOP_PARAMS
    ecu = RecordingEcu(p)
    o = ecu.out
    engine = StartEngine()
    cmd = {"arm": 0, "stop": 0, "sensors": 1, "demand": 1}
    script = _start_stop_script(o, engine, cmd)
    i = EcuInputs()
    dt = 1.0 / p.rate_hz
    for k in range(ticks):
        next(script)
        _engine_inputs(i, k, engine, o)
        i.arm, i.stop = cmd["arm"], cmd["stop"]
        i.sensor_status = E2E_OK if cmd["sensors"] else E2E_NONEWDATA
        i.analog_status = E2E_OK if k % 5 == 0 else E2E_NONEWDATA
        i.demand_status = E2E_OK if k % 5 == 0 and cmd["demand"] else E2E_NONEWDATA
        ecu.tick(i)
        engine.step(o, dt)
    return Golden("start-stop", compile_params(p), ecu.rows)


def _engine_inputs(i: EcuInputs, k: int, engine: StartEngine, o) -> None:  # noqa: ANN001 (EcuOutputs)
    """Tick ``k``'s readings of ``engine`` (a still rotor reads 0, a turning one has noise), a
    steady supply, the pump's current as the ECU drives it, a 45 %N demand."""
    i.tick = k % 65536
    noise = (k * 7919) % 41 - 20 if engine.n_pct > 0.5 else 0
    i.speed_rpm = max(0, round(engine.n_pct * 1125.0) + noise)
    i.egt_dk = round(engine.egt_k * 10.0)
    i.supply_mv = 22200
    i.pump_ma = (1050 + 60 * o.pump_mv // 1000) if o.pump_enable else 0
    i.demand_cpct = 4500
    i.open_loop_mv = 0


# the bench tests' script: (first tick, request, level, ms, arm, stop), held from that tick on
_BENCH_TEST_SCRIPT = (
    (20, 1, 0, 1000, 0, 0),  # the glow plug, 1 s
    (130, 0, 0, 0, 0, 0),
    (140, 2, 5000, 2000, 0, 0),  # a starter spin at the start's duty, 2 s: the rotor turns
    (350, 0, 0, 0, 0, 0),
    (360, 3, 1500, 500, 0, 0),  # a pump prime at 1.5 V, 0.5 s
    (420, 0, 0, 0, 0, 0),
    (430, 2, 99999, 1000, 0, 0),  # beyond the starter's duty: refused
    (440, 1, 0, 20000, 0, 0),  # beyond 10 s: refused
    (450, 0, 0, 0, 0, 0),
    (460, 2, 2000, 3000, 0, 0),  # a starter spin ended by a stop request
    (500, 2, 2000, 3000, 0, 1),
    (520, 0, 0, 0, 0, 0),
    (540, 1, 0, 1000, 0, 0),  # the glow plug ended by an arm: a start from rest to RUN
    (560, 1, 0, 1000, 1, 0),
    (600, 3, 1500, 500, 1, 0),  # a request while ARMED: refused by the firmware
    (900, 0, 0, 0, 0, 1),  # stop: SHUTDOWN, cool-down
    (960, 0, 0, 0, 0, 0),
)


def record_bench_tests(ticks: int) -> Golden:
    """The bench test functions (ecu.actuator_tests) on :class:`StartEngine`, with the start's
    parameters of START_STOP_PARAMS: the glow plug, a starter spin (the rotor turns and runs
    down), a pump prime, two requests beyond their limits, a test ended by a stop and one by an
    arm, which starts the engine to RUN; a request in ARMED; a stop and its cool-down."""
    p = START_STOP_PARAMS
    ecu = RecordingEcu(p)
    o = ecu.out
    engine = StartEngine()
    steps = {k: rest for k, *rest in _BENCH_TEST_SCRIPT}
    row = [0, 0, 0, 0, 0]
    i = EcuInputs()
    dt = 1.0 / p.rate_hz
    for k in range(ticks):
        row = steps.get(k, row)
        i.test_request, i.test_level, i.test_ms, i.arm, i.stop = row
        _engine_inputs(i, k, engine, o)
        i.sensor_status = E2E_OK
        i.analog_status = E2E_OK if k % 5 == 0 else E2E_NONEWDATA
        i.demand_status = E2E_OK if k % 5 == 0 else E2E_NONEWDATA
        ecu.tick(i)
        engine.step(o, dt)
    return Golden("bench-tests", compile_params(p), ecu.rows)


_HOT_LIMITS = """
description = "MRAC, hot day, speed limit steps up and down fast: limit loops, EGT line, allowance"
duration_s = 40
[plant]
model = "aero"
ambient_temperature_K = 318
[controller]
kind = "mrac"
params = { egt_limit_k = 1060, egt_gas_margin_k = 20, accel_max_pct_s = 5, decel_max_pct_s = 6 }
[command]
base = 0
[[command.component]]
kind = "staircase"
levels = [90, 100, 80, 95, 85]
step_s = 5
"""

_FAULTS = """
description = "MRAC with plant and sensor faults: pump halves, speed noise, speed stuck"
duration_s = 40
[plant]
model = "aero"
[controller]
kind = "mrac"
[command]
base = "trim"
[[command.component]]
kind = "square"
amplitude = 2.0
frequency_hz = 0.2
[[fault]]
time_s = 3
target = "PUMP_EFFECTIVENESS"
value = 0.5
[[fault]]
time_s = 8
target = "SPEED_NOISE"
value = 800
[[fault]]
time_s = 12
target = "SPEED_STUCK"
value = 1
"""

_RATE_FILTER = """
description = "PID and limit loops on the filtered speed rate: steps, speed noise, speed stuck"
duration_s = 30
[plant]
model = "aero"
[controller]
kind = "pid"
params = { rate_filter_on = 1, accel_max_pct_s = 5 }
[command]
base = 0
[[command.component]]
kind = "staircase"
levels = [90, 95, 85]
step_s = 5
[[fault]]
time_s = 8
target = "SPEED_NOISE"
value = 200
[[fault]]
time_s = 20
target = "SPEED_STUCK"
value = 1
"""

_EGT_OPEN = """
description = "PID, the EGT thermocouple opens (reads its upscale burnout value) at 3 s"
duration_s = 20
[plant]
model = "aero"
[controller]
kind = "pid"
[command]
base = "trim"
[[fault]]
time_s = 3
target = "EGT_OPEN_CIRCUIT"
value = 1
"""


_EGT_OVERTEMP = """
description = "PID without its limit loops, the turbine degrades at 3 s: EGT over its maximum"
duration_s = 10
[plant]
model = "aero"
[controller]
kind = "pid"
[controller.params]
limiters_on = 0
egt_limit_k = 1050
egt_max_k = 1100
start_egt_target_k = 1000  # the start's EGT limits under the lowered maximum (no start here)
start_egt_limit_k = 1100
[command]
base = "trim"
[[fault]]
time_s = 3
target = "TURBINE_EFFICIENCY"
value = 0.95
"""

_OVERSPEED = """
description = "Open loop, no limit loops, EGT trip and v_max raised: 21.9 V takes it over 105 %N"
duration_s = 10
[plant]
model = "aero"
[controller]
kind = "open_loop"
params = { limiters_on = 0, egt_limit_k = 1450, egt_max_k = 1550, v_max = 22.0 }
[command]
base = "trim"
[[command.component]]
kind = "ramp"
start_s = 1
end_s = 6
value = 9.5
"""


@dataclass(frozen=True)
class Source:
    record: Callable[[int], Golden]  # ticks -> vectors
    ticks: int  # default length: keeps the regeneration test short


_CHOP_PI = (
    (scenario.SCENARIO_DIR / "throttle-chop.toml")
    .read_text()
    .replace('kind = "mrac"', 'kind = "pi"')
)  # the PI's integrator started from an entry voltage other than the trim's


def _scenario(name: str, scenario_text: str, ticks: int) -> Source:
    return Source(lambda n: record_scenario(name, scenario_text, n), ticks)


SOURCES: dict[str, Source] = {
    "mrac-aero": _scenario("mrac-aero", "thesis-5.3-mrac-aero", 2500),
    "mrac-staircase": _scenario("mrac-staircase", "thesis-5.4-staircase", 2500),
    "pid-staircase": _scenario("pid-staircase", "thesis-6.2-staircase-pid", 2500),
    "pi-staircase": _scenario("pi-staircase", "staircase-pi", 2500),
    "open-loop-estimator": _scenario("open-loop-estimator", "thesis-4.3-estimator-aero", 2500),
    "estimator-reproducing": _scenario(
        "estimator-reproducing", "thesis-4.2-estimator-fast-reproducing", 2500
    ),
    "mrac-reproducing": _scenario("mrac-reproducing", "thesis-5.2-mrac-fast-reproducing", 2500),
    "limiters-hot": _scenario("limiters-hot", _HOT_LIMITS, 2500),
    "faults": _scenario("faults", _FAULTS, 2500),
    "rate-filter": _scenario("rate-filter", _RATE_FILTER, 2500),
    "egt-open": _scenario("egt-open", _EGT_OPEN, 1000),
    "egt-overtemp": _scenario("egt-overtemp", _EGT_OVERTEMP, 1000),
    "overspeed": _scenario("overspeed", _OVERSPEED, 1000),
    "accel-idle": _scenario("accel-idle", "accel-idle-to-max", 1200),
    "chop-pi": _scenario("chop-pi", _CHOP_PI, 1200),
    "modes": Source(record_modes, 2400),
    "start-stop": Source(record_start_stop, 2600),
    "bench-tests": Source(record_bench_tests, 1200),
}


def record(name: str, ticks: int | None = None) -> Golden:
    """The vectors of one source, for its default number of ticks or ``ticks``."""
    source = SOURCES[name]
    return source.record(source.ticks if ticks is None else ticks)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sil.run.golden", description=__doc__)
    parser.add_argument("out", type=Path, metavar="OUT_DIR")
    parser.add_argument("names", nargs="*", metavar="NAME", help=f"of {', '.join(SOURCES)}")
    parser.add_argument("--ticks", type=int, help="ticks per vector (default: each one's own)")
    args = parser.parse_args(argv)
    unknown = [n for n in args.names if n not in SOURCES]
    if unknown:
        parser.error(f"unknown vectors {unknown}; known: {', '.join(SOURCES)}")
    if args.ticks is not None and args.ticks < 1:
        parser.error("--ticks must be at least 1")
    args.out.mkdir(parents=True, exist_ok=True)
    for name in args.names or list(SOURCES):
        g = record(name, args.ticks)
        write(g, args.out / f"{name}.gv")
        print(f"{args.out / f'{name}.gv'}: {g.ticks} ticks")
    return 0


if __name__ == "__main__":
    sys.exit(main())
