"""Golden vectors for the C port (format: :mod:`ecu.golden`), recorded from the Python firmware
in closed loop.

Sources:
- SIL scenarios run in one process (command node, ECU, plant as in ``sil run --mode inproc``),
  cut to their first ticks: MRAC, PID and open loop on the aero-thermal plant, plant and sensor
  faults, limit loops on a hot day, the transients from idle and from maximum (an entry voltage
  other than the trim's);
- a scripted sequence for what the SIL never does (it arms once and runs): OFF, ARMED, RUN,
  SHUTDOWN and a latched FAULT, lost and corrupt frames, pump current faults.

    python -m sil.golden OUT_DIR [NAME ...] [--ticks N]   write the vectors (all: no NAME)
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ecu import modes
from ecu.firmware import E2E_NONEWDATA, E2E_OK, E2E_WRONGCRC, EcuInputs
from ecu.firmware_params import compile_params
from ecu.golden import Golden, RecordingEcu, write
from ecu.node import EcuNode
from ecu.params import EcuParams
from plant.fast_model import FastEngine
from plant.node import PlantNode
from protocol.codec import Codec
from protocol.node import InProcessBus
from sil import profiles, runner, scenario
from sil.command_node import CommandNode
from sil.recorder import Recorder


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
    fast model while the ECU runs.
    """
    p = EcuParams()
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


_HOT_LIMITS = """
description = "MRAC on a hot day, steps up to the speed limit and down fast: limit loops engage"
duration_s = 40
[plant]
model = "aero"
ambient_temperature_K = 318
[controller]
kind = "mrac"
params = { egt_limit_k = 1060, accel_max_pct_s = 5, decel_max_pct_s = 6 }
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
params = { limiters_on = 0, egt_limit_k = 1050, egt_max_k = 1100 }
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
}


def record(name: str, ticks: int | None = None) -> Golden:
    """The vectors of one source, for its default number of ticks or ``ticks``."""
    source = SOURCES[name]
    return source.record(source.ticks if ticks is None else ticks)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sil.golden", description=__doc__)
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
