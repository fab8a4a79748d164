"""Where a run stands: its status, node processes, bus, recorder, tags and what it has
to say, shared by the runner, the node processes' watch and the summary."""

from __future__ import annotations

import subprocess
from dataclasses import dataclass, field

import can

from protocol.bus import BusSpec
from protocol.run_bus import RunBus
from protocol.run_tag import TagClaim
from sil.run.recorder_process import RecorderProcess
from sil.run.watchdog import TurnWatch


@dataclass
class RunState:
    status: str = "completed"
    abort_reason: str | None = None
    children: dict[str, subprocess.Popen] = field(default_factory=dict)
    bus: str = "none (in process)"
    loop: str | None = None  # in process: "compiled" (sil/run/compiled_loop.py) or "python"
    ecu_bus: str | None = None  # the ECU's side of the fault bridge
    bridge_errors: list[str] = field(default_factory=list)  # frames the bridge could not send
    bus_fault_events: list[dict] = field(default_factory=list)
    recorder: RecorderProcess | None = None  # the recorder's process, made before the set-up
    ecu_heard: dict[int, float] | None = None  # the fault bridge's ECU side: ID -> when heard
    started: float = 0.0  # perf_counter when the run began
    started_wall: float = 0.0  # time.time() then (the start of the log's MF4 copy)
    nodes_up: float | None = None  # perf_counter when the node processes were up, at tick 0
    run_id: int | None = None  # on a bus: this run's RunId (its SimRun beacons carry it)
    claims: list[TagClaim] = field(default_factory=list)  # the run's tags: run bus, ECU bus
    run_bus: RunBus | None = None  # the command node's bus: its foreign-frame counts
    senders: dict[str, str] | None = None  # the run's senders (node -> token), where named
    warnings: list[str] = field(default_factory=list)  # said on stderr and in the summary
    record: dict = field(default_factory=dict)  # what shaped the run (run.json)
    specs: tuple[BusSpec, BusSpec] | None = None  # on a bus: the run's bus and the ECU's
    bus_handle: can.BusABC | None = None  # the command node's bus, opened before the run
    write_errors: list[str] = field(default_factory=list)  # results that could not be written
    turn_watch: TurnWatch | None = None  # lockstep without bus faults: the mid-run watch
    ended_early: dict | None = None  # a run short of its last tick: which node, when and why

    def close_bus(self) -> None:
        """Shut the command node's bus if the run did not take it over."""
        if self.bus_handle is not None:
            self.bus_handle.shutdown()
            self.bus_handle = None

    def take_bus(self) -> can.BusABC:
        """The command node's bus, opened by the input checks; from now on the caller's."""
        bus, self.bus_handle = self.bus_handle, None
        assert bus is not None
        return bus

    def release(self) -> None:
        """Give back the run's tags (once the node processes are stopped)."""
        for claim in self.claims:
            claim.release()
