"""An in-process run: its nodes (the compiled loop with the C ECU, else the Python nodes around
either ECU) flown in this process, through the in-process bus (with the bus faults' injector
where the scenario has them) or the compiled loop."""

from __future__ import annotations

from ecu.firmware_params import compile_params
from ecu.node import EcuNode
from ecu.params import EcuParams
from ecu.port.core import make_ecu
from ecu.port.node import CEcuNode
from plant.interface import Plant
from plant.node import PlantNode
from protocol.node import InProcessBus
from sil.busfault.injector import Injector
from sil.busfault.inproc import FaultyInProcessBus
from sil.run.command_node import CommandNode
from sil.run.compiled_loop import CompiledLoop, compile_loop
from sil.run.config import RunOptions
from sil.run.state import RunState
from sil.scenario import Scenario


def inproc_nodes(opts: RunOptions, s: Scenario, params: EcuParams, plant: Plant) -> list:
    """The ECU and plant nodes of an in-process run: for the compiled loop (the C ECU, no bus
    faults, a plant with a compiled node; unless ``opts.compiled_loop`` is off) the C node."""
    ecu = make_ecu(opts.ecu_impl, compile_params(params))
    plant_node = PlantNode(plant)
    if opts.compiled_loop and opts.ecu_impl == "c" and not s.bus_faults and plant_node.compiled():
        compile_loop()
        return [CEcuNode(ecu), plant_node]
    return [EcuNode(ecu=ecu), plant_node]


def fly(
    s: Scenario, seed: int, command: CommandNode, built: list, state: RunState, progress
) -> None:  # noqa: ANN001 (the runner's progress)
    """Fly the run in this process until the command node is finished: ``built`` the nodes of
    :func:`inproc_nodes`, started after the command node (the plant's tick 0 last)."""
    if state.loop == "compiled":
        CompiledLoop(command, *built, command.recorder).run(progress)
    elif s.bus_faults:
        injector = Injector(s.bus_faults, s.ecu_rate_hz, seed, command.codec)
        FaultyInProcessBus(command, *built, injector).run(done=lambda: command.finished)
        state.bus_fault_events = injector.events
    else:
        InProcessBus([command, *built]).run(done=lambda: command.finished)
