"""One campaign case: the scenario's three nodes in this process with a :class:`Probe`.

The same nodes and order as ``sil run --mode inproc`` (:mod:`sil.run.runner`), so the figures equal
those of the printed ``sil run`` command line; only the recording is left out. With the C ECU and
no bus faults, as there, the nodes run in the compiled loop (:mod:`sil.run.compiled_loop`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import cache

import numpy as np
from cantools.database.can import Database

from ecu.firmware_params import compile_params
from ecu.node import EcuNode
from ecu.params import EcuParams
from ecu.port.core import make_ecu
from ecu.port.node import CEcuNode
from plant.node import PlantNode
from protocol.codec import Codec
from protocol.dbc import load_database
from protocol.node import InProcessBus
from sil.busfault.injector import Injector
from sil.busfault.inproc import FaultyInProcessBus
from sil.campaign.probe import Probe
from sil.run.command_node import CommandNode
from sil.run.compiled_loop import CompiledLoop, compile_loop
from sil.run.config import build_plant, ecu_params
from sil.scenario import Scenario, profiles


@dataclass
class CaseRun:
    """What a case leaves for the metrics and invariants."""

    scenario: Scenario
    params: EcuParams
    probe: Probe
    ticks: int  # ticks the scenario asked for
    wall_s: float
    bus_events: list[dict] = field(default_factory=list)
    stalls: dict[str, int] = field(default_factory=dict)
    demand: np.ndarray = field(default_factory=lambda: np.zeros(0))  # the command per tick

    def column(self, name: str) -> np.ndarray:
        return np.asarray(getattr(self.probe, name))


@cache
def _database() -> Database:
    """The DBC, parsed once per process (three quarters of a codec's build): each case builds
    its codec on it, with counters of its own."""
    return load_database()


def run_case(
    s: Scenario, seed: int | None = None, ecu_impl: str = "python", compiled_loop: bool = True
) -> CaseRun:
    """Run a case; ``ecu_impl``: the firmware's Python original or its C port (ecu.port), which
    runs in the compiled loop unless ``compiled_loop`` is off (or there are bus faults)."""
    seed = s.seed if seed is None else seed
    t0 = time.perf_counter()
    plant = build_plant(s, seed)
    params = ecu_params(s, plant)
    open_loop = s.controller.kind == "open_loop"
    trim_value = plant.trim_pump_voltage if open_loop else params.trim_n_pct
    commands = profiles.sample(s.profile(trim_value), s.duration_s, s.ecu_rate_hz)
    codec = Codec(database=_database())
    out = plant.outputs
    probe = Probe(codec, lambda: (out.n_pct, out.egt_true_k, out.p3_pa, out.thrust_n, out.flags))
    command = CommandNode(
        codec,
        probe,
        commands,
        ecu_rate_hz=s.ecu_rate_hz,
        open_loop=open_loop,
        faults=s.faults,
        stop_tick=s.stop_tick,
    )
    # one codec for all three (18 ms each to build): each node packs only its own messages
    core = make_ecu(ecu_impl, compile_params(params))
    plant_node = PlantNode(plant, codec=codec)
    events: list[dict] = []
    stalls: dict[str, int] = {}
    if compiled_loop and ecu_impl == "c" and not s.bus_faults and plant_node.compiled():
        compile_loop()
        loop = CompiledLoop(command, CEcuNode(core, codec=codec), plant_node, probe)
        loop.run()
        probe.take_truth(loop.truth)
        return CaseRun(s, params, probe, len(commands), time.perf_counter() - t0, demand=commands)
    ecu = EcuNode(ecu=core, codec=codec)
    if s.bus_faults:
        injector = Injector(s.bus_faults, s.ecu_rate_hz, seed, codec)
        bus = FaultyInProcessBus(command, ecu, plant_node, injector)
        bus.run(done=lambda: command.finished)
        events, stalls = injector.events, bus.stalls
    else:
        InProcessBus([command, ecu, plant_node]).run(done=lambda: command.finished)
    wall = time.perf_counter() - t0
    return CaseRun(s, params, probe, len(commands), wall, events, stalls, demand=commands)
