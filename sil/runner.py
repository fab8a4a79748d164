"""Run a scenario: the plant, the ECU and the command node, over a bus or in one process.

- ``lockstep`` (default) and ``realtime``: the plant and the ECU are separate processes
  (``sil plant``, ``sil ecu``) on the chosen bus; this process is the command node and the
  recorder. Children die with this process (PR_SET_PDEATHSIG) and are stopped at the end.
- ``inproc``: the same three nodes in this process through the same codec, with no bus.

Bus faults (``[[bus_fault]]``) act in process in ``inproc`` mode; on a bus the ECU goes on a second
bus and this process bridges the two through the injector (:mod:`sil.busfault.bridge`), counting
time by the plant's sensor frames in lockstep and by the wall clock in real time. The recorder
listens on the plant's side.

On a bus the run claims a tag (:mod:`protocol.run_tag`) for the run's time and every node reads
the bus through :class:`protocol.run_bus.RunBus`, so runs sharing a bus keep apart; the summary
counts the other runs' frames that were dropped.

If a node process dies, or on Ctrl-C, the run keeps recording for a short grace period (to capture
the other node's reaction), stops the rest, writes everything recorded so far and marks the
summary aborted with the reason.
"""

from __future__ import annotations

import gc
import json
import math
import os
import signal
import subprocess
import sys
import time
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path

import can
import numpy as np

from ecu import commissioning
from ecu import faults as ecu_faults
from ecu.firmware_params import compile_params
from ecu.node import EcuNode
from ecu.params import EcuParams, preset
from ecu.port.core import make_ecu
from ecu.port.node import CEcuNode
from plant.aerothermal import AeroThermalPlant
from plant.fast_plant import FastPlant
from plant.faults import Fault, FaultKind
from plant.interface import Ambient, Battery, Plant, PlantConfig
from plant.node import PlantNode
from plant.sensors import SpeedPickupConfig, ThermocoupleConfig
from protocol.bus import BusSpec, BusSpecError, default_spec, open_bus, parse_spec, unique_udp_spec
from protocol.busload import bus_load_pct
from protocol.codec import Codec
from protocol.node import DriverStats, InProcessBus, bus_batch_receiver, bus_sender, unusable
from protocol.run_bus import RunBus
from protocol.run_sequence import RunSequence, sent_by
from protocol.run_tag import TagClaim, claim_tag
from sil import metrics, profiles, results, run_folder, run_record
from sil.busfault.bridge import Bridge, SensorTicks, WallTicks
from sil.busfault.injector import Injector
from sil.busfault.inproc import FaultyInProcessBus
from sil.canlog import convert
from sil.command_node import CommandNode
from sil.compiled_loop import CompiledLoop, compile_loop
from sil.parent_death import PEER_LOST_SIGNAL, child_env, die_with_parent
from sil.recorder import Recorder
from sil.recorder_process import RecorderFailed, RecorderProcess
from sil.run_record import Overrides
from sil.scenario import HEALTH, PlantSettings, Scenario
from sil.ticks import ACTUATOR, ECU_IDS, PLANT_IDS, SENSORS
from sil.watchdog import Starting, StartWatch, TurnWatch, Watchdog, interrupt_reason

# fault bits listed in the summary: all but the two that only describe the present tick
REPORTED_FAULTS = {
    bit: name
    for bit, name in ecu_faults.NAMES.items()
    if not bit & (ecu_faults.LIMITER_ACTIVE | ecu_faults.PUMP_SATURATED)
}
NODE_GUARD_S = 2.0  # lockstep with bus faults: silence after which a node runs on its own clock
GRACE_S = NODE_GUARD_S + 2.0  # recording continues this long after a node died
# lockstep without bus faults: a node waits for its peer as long as the run lets it (the run's
# TurnWatch tells a slow peer from a dead one, and tells the node when its peer is dead)
LOCKSTEP_GUARD_S = 3600.0
PEER_GRACE_S = 0.5  # ... then records this long, the node on its own clock, before it ends
# lockstep on a bus that hands over every frame queued at once (the loopback bus): the command
# node reads it at most this often while frames come; they queue in between, so that one read
# takes a tick's frames and no sender has to wake this process for each of them
LOCKSTEP_READ_S = 100e-6
READY_POLL_S = 0.02  # how often the start-up looks at the node processes
BRIDGED_GUARD_S = 0.25  # lockstep through the fault bridge: a lost frame costs this much wall time


@dataclass
class RunOptions:
    scenario: Scenario
    out_dir: Path
    mode: str = "lockstep"
    bus: str | None = None
    seed: int | None = None
    log_formats: tuple[str, ...] = ()
    plots: bool = True
    progress: bool = True
    commission: Path | None = None  # `sil identify --export` file for the ECU
    ecu_impl: str = "python"  # ECU tick: the Python firmware, its C port ("c", ecu/port) or
    # the C firmware image on QEMU ("pil", ecu/port/pil.py; on a bus only)
    pil_link: str = "eth"  # the image's CAN link (ecu.port.build.PIL_LINKS: eth or slcan)
    ecu_extra_args: tuple[str, ...] = ()  # appended to `sil ecu` (e.g. --serial pty)
    ecu_bus: str | None = None  # the ECU's side of the fault bridge (default: a second udp bus)
    compiled_loop: bool = True  # inproc with the C ECU: one compiled loop (sil/compiled_loop.py)
    overrides: Overrides = field(default_factory=Overrides)  # --controller, --param, ...
    command_line: tuple[str, ...] = ()  # the command that asked for the run, for run.json


@dataclass
class RunState:
    status: str = "completed"
    abort_reason: str | None = None
    children: dict[str, subprocess.Popen] = field(default_factory=dict)
    bus: str = "none (in process)"
    loop: str | None = None  # in process: "compiled" (sil/compiled_loop.py) or "python"
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
    warnings: list[str] = field(default_factory=list)  # said on stderr and in the summary
    record: dict = field(default_factory=dict)  # what shaped the run (run.json)
    specs: tuple[BusSpec, BusSpec] | None = None  # on a bus: the run's bus and the ECU's
    bus_handle: can.BusABC | None = None  # the command node's bus, opened before the run
    write_errors: list[str] = field(default_factory=list)  # results that could not be written
    turn_watch: TurnWatch | None = None  # lockstep without bus faults: the mid-run watch

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


def plant_config(s: Scenario, seed: int, *, nominal: bool = False) -> PlantConfig:
    """The scenario's plant; ``nominal``: the engine the ECU is commissioned for, without the
    engine-to-engine variation and at the eq. 2.32 trim whatever the scenario starts from."""
    p = s.plant
    config = PlantConfig(
        ecu_period_s=1.0 / s.ecu_rate_hz,
        ambient=Ambient(p.ambient_temperature_K, p.ambient_pressure_Pa, p.flight_speed_m_s),
        battery=Battery(p.supply_voltage_V),
        seed=seed,
    )
    if nominal:
        return config
    config = replace(
        config, initial_speed_pct=p.initial_speed_pct, initial_egt_max_k=p.initial_egt_max_K
    )
    if p.standstill:
        config = replace(config, standstill=True)
    if not p.varied:
        return config
    return replace(
        config,
        **{k: getattr(p, k) for k in HEALTH},
        pump_gain=p.pump_gain,
        faults=(Fault(0.0, FaultKind.PUMP_WEAR, p.pump_wear_per_s),) if p.pump_wear_per_s else (),
        speed_pickup=SpeedPickupConfig(noise_rpm=p.speed_noise_rpm, bias_rpm=p.speed_bias_rpm),
        thermocouple=ThermocoupleConfig(noise_k=p.egt_noise_K, bias_k=p.egt_bias_K),
    )


def build_plant(s: Scenario, seed: int, *, nominal: bool = False) -> Plant:
    config = plant_config(s, seed, nominal=nominal)
    return AeroThermalPlant(config) if s.plant.model == "aero" else FastPlant(config)


def ecu_trim_voltage(s: Scenario, plant: Plant) -> float:
    """The ECU's trim voltage: the nominal engine's at its trim (the ECU is not told how its
    engine varies, nor where the scenario starts it)."""
    if not s.plant.varied and s.plant.initial_speed_pct is None and not s.plant.standstill:
        return plant.trim_pump_voltage
    return build_plant(s, 0, nominal=True).trim_pump_voltage


def ecu_overrides(s: Scenario, trim_v: float, entry_v: float) -> dict[str, object]:
    """The scenario's ECU parameters over its preset's; ``entry_v``: the pump voltage holding the
    plant's initial state, which the ECU takes over (as if it had held it before the run)."""
    overrides: dict[str, object] = {
        "controller": s.controller.kind,
        "rate_hz": int(round(s.ecu_rate_hz)),
        "trim_v": trim_v,
        "entry_v": entry_v,
    }
    if s.controller.reading is not None:
        overrides["reading"] = s.controller.reading
    overrides.update(s.controller.params)
    return overrides


def ecu_params(s: Scenario, plant: Plant) -> EcuParams:
    """The ECU's parameters for a run of scenario s on this plant."""
    trim_v = ecu_trim_voltage(s, plant)
    params = preset(s.controller.preset or "default", **ecu_overrides(s, trim_v, trim_v))
    # the plant may hold its start beyond the ECU's range (a weak pump at maximum speed): the ECU
    # takes over at the nearest voltage it may command
    return replace(params, entry_v=min(max(plant.trim_pump_voltage, params.v_min), params.v_max))


def _spawn(name: str, args: list[str], out_dir: Path) -> subprocess.Popen:
    log = (out_dir / f"{name}.log").open("w")
    env = {**os.environ, "PYTHONUNBUFFERED": "1", **child_env()}
    return subprocess.Popen(
        [sys.executable, "-m", "sil.cli", *args],
        stdout=log,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        env=env,
        preexec_fn=die_with_parent if sys.platform == "linux" else None,  # (before exec)
    )


def _stop(children: dict[str, subprocess.Popen]) -> None:
    for proc in children.values():
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            proc.send_signal(signal.SIGCONT)  # a stopped process takes the SIGTERM then
    deadline = time.monotonic() + 3.0
    for proc in children.values():
        try:
            proc.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


class _Progress:
    def __init__(self, total: int, enabled: bool, label: str) -> None:
        self.bar = None
        if enabled and sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(
                total=total, unit="tick", desc=label, leave=False, mininterval=0.5, smoothing=0.1
            )
        self.done = 0

    def __call__(self, tick: int) -> None:
        if self.bar is not None and tick - self.done >= 200:
            self.bar.update(tick - self.done)
            self.done = tick

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def run(opts: RunOptions) -> dict:
    """Run the scenario, write can.log, trace.csv, summary.json and plots; return the summary.

    Every input (the scenario and commissioning files, the ECU parameters, the bus, ``--out``)
    is checked before the run folder is touched; a refusal raises ValueError (BusSpecError,
    :class:`~sil.run_folder.FolderError`) and leaves the folder as it was. The folder is then
    made and locked for the run's time (:class:`~sil.run_folder.FolderLock`), cleared of an
    earlier run's files and marked running. A result that cannot be written raises
    :class:`~sil.results.WriteError` before the run began; once it flew, the run is aborted
    with the file named."""
    s = opts.overrides.apply(opts.scenario)
    seed = s.seed if opts.seed is None else opts.seed
    record = run_record.prepare(s, seed, _shaped_by(opts), opts.commission)
    record.check()
    state = RunState()
    _check_inputs(opts, s, state)
    try:
        run_folder.check("--out", opts.out_dir)
        lock = run_folder.FolderLock(opts.out_dir)
    except BaseException:
        state.close_bus()
        raise
    with lock:
        return _run_in_folder(opts, s, seed, record, state)


def _check_inputs(opts: RunOptions, s: Scenario, state: RunState) -> None:
    """Refuse, before the run folder is touched, what the run could not fly: ``--ecu-impl pil``
    in process, a bus that cannot be opened (it is opened here, for the run), a commissioning
    file the ECU would refuse, ECU parameters it would refuse (checked at the preset's trim;
    the run's own trim is checked again once the plant is built)."""
    if opts.mode == "inproc" and opts.ecu_impl == "pil":
        raise ValueError("--ecu-impl pil runs the image on a bus: use --mode lockstep or "
                         "realtime")  # fmt: skip
    nominal = {
        k: v for k, v in ecu_overrides(s, 0.0, 0.0).items() if k not in ("trim_v", "entry_v")
    }
    params = preset(s.controller.preset or "default", **nominal)
    if opts.commission is not None:
        params = commissioning.commission(params, opts.commission)
    compile_params(params)
    if opts.mode == "inproc":
        return
    spec = _bus_spec(opts)
    ecu_spec = _ecu_side(opts, spec) if s.bus_faults else spec
    state.specs = (spec, ecu_spec)
    state.bus_handle = open_bus(spec)


def _run_in_folder(
    opts: RunOptions, s: Scenario, seed: int, record: run_record.Pending, state: RunState
) -> dict:
    """The run, its folder locked: cleared, marked running, flown, its results written."""
    try:
        results.clear(opts.out_dir)  # an earlier run's files never pass for this one's
        results.mark(opts.out_dir, "running", s.name)
        state.record = record.write(opts.out_dir)
        return _run(opts, s, seed, state)
    except BaseException as exc:
        state.close_bus()
        _mark_failed(opts.out_dir, s.name, _failure(exc, state))
        _stop(state.children)
        state.release()
        if state.recorder is not None:
            state.recorder.discard()
        for name in state.children:  # refused in set-up: a process stopped before it said a word
            log = opts.out_dir / f"{name}.log"
            if log.exists() and log.stat().st_size == 0:
                log.unlink()
        raise


def _mark_failed(out_dir: Path, scenario: str, reason: str) -> None:
    """The summary of a run that failed: ``failed`` with the reason, if it can be written."""
    try:
        results.mark(out_dir, "failed", scenario, reason)
    except OSError:
        try:
            summary = {"status": "failed", "abort_reason": reason, "scenario": scenario}
            results.write_summary_in_place(out_dir, summary)
        except OSError:
            pass  # (the error that failed the run is reported)


def _shaped_by(opts: RunOptions) -> dict:
    """The options that shaped a run, for its record (run.json): with the seed and the scenario
    as run, what it takes to repeat or replay it."""
    return {
        **({"command_line": list(opts.command_line)} if opts.command_line else {}),
        "mode": opts.mode,
        "bus": opts.bus,
        **({"ecu_bus": opts.ecu_bus} if opts.ecu_bus else {}),
        "ecu_impl": opts.ecu_impl,
        **({"pil_link": opts.pil_link} if opts.ecu_impl == "pil" else {}),
        **({"compiled_loop": False} if not opts.compiled_loop else {}),
        "overrides": opts.overrides.as_dict(),
    }


def _failure(exc: BaseException, state: RunState) -> str:
    """The reason a run failed by ``exc`` gives in its summary."""
    what = interrupt_reason(exc) if isinstance(exc, KeyboardInterrupt) else str(exc)
    what = what or type(exc).__name__
    return what if state.started else f"{what} (before the run began)"


def _run(opts: RunOptions, s: Scenario, seed: int, state: RunState) -> dict:
    """The run; should it raise, the caller stops ``state.children`` and discards
    ``state.recorder``."""
    spec = ecu_spec = None
    # the processes first, so that their start-up overlaps the set-up: the recorder's (it imports
    # meanwhile), the plant's (1-1.5 s), and below the ECU's once its parameters are checked
    if opts.mode != "realtime" and not s.bus_faults:
        state.recorder = RecorderProcess()
    if opts.mode != "inproc":
        assert state.specs is not None
        spec, ecu_spec = state.specs
        state.bus = str(spec)
        state.ecu_bus = str(ecu_spec) if s.bus_faults else None
        state.run_id = int.from_bytes(os.urandom(4), "little")
        state.claims = [claim_tag(str(spec))]
        if s.bus_faults:
            state.claims.append(claim_tag(str(ecu_spec)))
        for path in _handshake_files(opts.out_dir):
            path.unlink(missing_ok=True)
        ticks = profiles.tick_count(s.duration_s, s.ecu_rate_hz) + 1  # 0 .. last: len(commands)
        state.children["plant"] = _spawn(
            "plant", _plant_args(opts, s, seed, spec, state.claims[0].tag, ticks), opts.out_dir
        )
    plant = build_plant(s, seed)
    params = ecu_params(s, plant)
    if opts.commission is not None:
        params = commissioning.commission(params, opts.commission)
    compile_params(params)  # refuse bad overrides before anything starts
    if ecu_spec is not None:
        ecu_args = _ecu_args(opts, s, params, ecu_spec, state.claims[-1].tag)
        state.children["ecu"] = _spawn("ecu", ecu_args, opts.out_dir)
    open_loop = s.controller.kind == "open_loop"
    trim_value = plant.trim_pump_voltage if open_loop else params.trim_n_pct
    commands = profiles.sample(s.profile(trim_value), s.duration_s, s.ecu_rate_hz)
    if not open_loop:
        state.warnings += demand_warnings(s, commands, params)
    for warning in state.warnings:
        print(f"sil run: warning: {warning}", file=sys.stderr)
    period = 1.0 / s.ecu_rate_hz
    # in process, the ECU and plant nodes are built before the clock starts, as the plant is
    built: list = []
    if opts.mode == "inproc":
        built = _inproc_nodes(opts, s, params, plant)
        state.loop = "compiled" if isinstance(built[0], CEcuNode) else "python"
    del plant  # (on a bus the plant runs in its own process)
    codec = Codec()
    recorder: Recorder | RecorderProcess
    if state.recorder is not None:
        # in process the run's clock starts once the recorder is made; on a bus, its start-up
        # overlaps the node processes', which the run counts (startup_s)
        wait = opts.mode == "inproc"
        recorder = state.recorder.open(opts.out_dir, period, commands=commands, wait=wait)
        state.recorder = None  # from here on the run closes it
    else:
        recorder = Recorder(
            opts.out_dir, codec, period, commands=commands, wall_clock=opts.mode == "realtime"
        )
    progress = _Progress(len(commands), opts.progress, s.name)
    command = CommandNode(
        codec,
        recorder,
        commands,
        ecu_rate_hz=s.ecu_rate_hz,
        open_loop=open_loop,
        faults=s.faults,
        progress=progress,
        realtime=opts.mode == "realtime",
        run_id=state.run_id,
        stop_tick=s.stop_tick,
    )
    # What exists now (numba, the codec, the nodes...) lives through the run: frozen, it is
    # skipped by the collector's full passes, each of which would stall the run for 0.1 s.
    gc.freeze()
    state.started = time.perf_counter()
    state.started_wall = time.time()
    try:
        if opts.mode == "inproc":
            nodes = [command, *built]  # started in this order: the plant's tick 0 last
            if state.loop == "compiled":
                CompiledLoop(command, *built, recorder).run(progress)
            elif s.bus_faults:
                injector = Injector(s.bus_faults, s.ecu_rate_hz, seed, codec)
                FaultyInProcessBus(*nodes, injector).run(done=lambda: command.finished)
                state.bus_fault_events = injector.events
            else:
                InProcessBus(nodes).run(done=lambda: command.finished)
        else:
            assert spec is not None and ecu_spec is not None
            _run_on_bus(opts, s, seed, (spec, ecu_spec), command, state)
    except KeyboardInterrupt as exc:
        state.status, state.abort_reason = "aborted", interrupt_reason(exc)
    except (RecorderFailed, results.WriteError) as exc:  # the recorder's files, a full disk
        _recording_failed(state, exc)
    finally:
        _stop(state.children)
        state.release()
        progress.close()
        try:
            recorder.close()
        except (RecorderFailed, results.WriteError) as exc:
            _recording_failed(state, exc)
        except KeyboardInterrupt as exc:  # came while the recorder finished its files: they stand
            state.status = "aborted"
            state.abort_reason = state.abort_reason or interrupt_reason(exc)
        gc.unfreeze()
    wall = time.perf_counter() - state.started
    return _finish(opts, s, seed, recorder, command, state, wall)


def _recording_failed(state: RunState, exc: RecorderFailed | results.WriteError) -> None:
    """The recorder failed (its process died, or a file could not be written): the run is
    aborted with the first such reason."""
    state.status = "aborted"
    state.abort_reason = state.abort_reason or str(exc)
    if isinstance(exc, results.WriteError) or getattr(exc, "write_error", False):
        state.write_errors.append(str(exc))


def _inproc_nodes(opts: RunOptions, s: Scenario, params: EcuParams, plant: Plant) -> list:
    """The ECU and plant nodes of an in-process run: for the compiled loop (the C ECU, no bus
    faults, a plant with a compiled node; unless ``opts.compiled_loop`` is off) the C node."""
    ecu = make_ecu(opts.ecu_impl, compile_params(params))
    plant_node = PlantNode(plant)
    if opts.compiled_loop and opts.ecu_impl == "c" and not s.bus_faults and plant_node.compiled():
        compile_loop()
        return [CEcuNode(ecu), plant_node]
    return [EcuNode(ecu=ecu), plant_node]


def _bus_spec(opts: RunOptions) -> BusSpec:
    if opts.bus:
        return parse_spec(opts.bus)
    spec, why = default_spec()
    print(why, file=sys.stderr)
    return spec


def _ready_file(out_dir: Path, node: str) -> Path:
    """Where a node process says it is ready (``--ready-file``)."""
    return out_dir / f".{node}-ready"


def _start_file(out_dir: Path) -> Path:
    """The plant's go (``sil plant --start-file``): tick 0 goes out once it exists."""
    return out_dir / ".plant-start"


def _handshake_files(out_dir: Path) -> tuple[Path, ...]:
    """The node processes' ready files, the plant's start file and their stats files."""
    nodes = ("ecu", "plant")
    return (
        *(_ready_file(out_dir, n) for n in nodes),
        _start_file(out_dir),
        *(_stats_file(out_dir, n) for n in nodes),
    )


def _strict(opts: RunOptions, s: Scenario) -> bool:
    """A lockstep run without bus faults: one sequence of frames, each node waiting for its
    peer as long as the run lets it (no node runs on its own clock)."""
    return opts.mode == "lockstep" and not s.bus_faults


def _guard_s(opts: RunOptions, s: Scenario) -> float:
    if _strict(opts, s):
        return LOCKSTEP_GUARD_S
    return BRIDGED_GUARD_S if s.bus_faults and opts.mode == "lockstep" else NODE_GUARD_S


def _foreign_frames(opts: RunOptions, s: Scenario) -> str:
    """The nodes' --foreign-frames: the run's sequence in lockstep without bus faults, else
    only their own IDs (protocol.run_sequence)."""
    return "sequence" if _strict(opts, s) else "ids"


def _plant_args(
    opts: RunOptions, s: Scenario, seed: int, spec: BusSpec, tag: int, ticks: int
) -> list[str]:
    p = s.plant
    args = [
        "plant",
        "--bus",
        str(spec),
        "--run-tag",
        str(tag),
        "--model",
        p.model,
        "--rate-hz",
        str(int(round(s.ecu_rate_hz))),
        "--ticks",
        str(ticks + 1),
        "--t0",
        repr(p.ambient_temperature_K),
        "--p0",
        repr(p.ambient_pressure_Pa),
        "--flight-speed",
        repr(p.flight_speed_m_s),
        "--battery-v",
        repr(p.supply_voltage_V),
        "--seed",
        str(seed),
        "--guard-s",
        str(_guard_s(opts, s)),
        "--foreign-frames",
        _foreign_frames(opts, s),
        "--ready-file",
        str(_ready_file(opts.out_dir, "plant")),
        "--start-file",
        str(_start_file(opts.out_dir)),
        "--stats-file",
        str(_stats_file(opts.out_dir, "plant")),
    ]
    if p.initial_speed_pct is not None:
        args += ["--initial-speed", repr(p.initial_speed_pct)]
        if math.isfinite(p.initial_egt_max_K):
            args += ["--initial-egt-max", repr(p.initial_egt_max_K)]
    if p.standstill:
        args.append("--standstill")
    if p.varied:
        args += _variation_args(p)
    if opts.mode == "realtime":
        args.append("--realtime")
    return args


def _variation_args(p: PlantSettings) -> list[str]:
    """``sil plant``'s options for the engine's variation from the nominal one (as
    :func:`plant_config` builds it in process)."""
    nominal = PlantSettings()
    args = []
    for name, option in (
        *((k, k) for k in HEALTH),
        ("pump_gain", "pump_gain"),
        ("speed_noise_rpm", "speed_noise_rpm"),
        ("speed_bias_rpm", "speed_bias_rpm"),
        ("egt_noise_K", "egt_noise_k"),
        ("egt_bias_K", "egt_bias_k"),
    ):
        value = getattr(p, name)
        if value != getattr(nominal, name):
            args += [f"--{option.replace('_', '-')}", repr(value)]
    if p.pump_wear_per_s:
        args += ["--fault", f"0:{FaultKind.PUMP_WEAR.value}:{p.pump_wear_per_s!r}"]
    return args


def _ecu_args(
    opts: RunOptions, s: Scenario, params: EcuParams, ecu_spec: BusSpec, tag: int
) -> list[str]:
    args = [
        "ecu",
        "--bus",
        str(ecu_spec),
        "--run-tag",
        str(tag),
        "--mode",
        opts.mode,
        "--preset",
        s.controller.preset or "default",
        "--ready-file",
        str(_ready_file(opts.out_dir, "ecu")),
        "--guard",
        str(_guard_s(opts, s)),
        "--foreign-frames",
        _foreign_frames(opts, s),
        "--json",
        "--impl",
        opts.ecu_impl,
        *(("--pil-link", opts.pil_link) if opts.ecu_impl == "pil" else ()),
        "--stats-file",
        str(_stats_file(opts.out_dir, "ecu")),
    ]
    if opts.commission is not None:
        args += ["--commission", str(opts.commission)]
    for name, value in ecu_overrides(s, params.trim_v, params.entry_v).items():
        if name == "controller":
            args += ["--controller", str(value)]
        elif name == "rate_hz":
            args += ["--rate", str(value)]
        elif name == "reading":
            args += ["--reading", str(value)]
        else:
            args += ["--param", f"{name}={value!r}"]
    return args + list(opts.ecu_extra_args)


def _run_on_bus(
    opts: RunOptions,
    s: Scenario,
    seed: int,
    specs: tuple[BusSpec, BusSpec],
    command: CommandNode,
    state: RunState,
) -> None:
    """The node processes are starting (see ``_run``): wait until both are ready, then play.
    ``specs``: the run's bus and the ECU's (the same bus unless there are bus faults)."""
    spec, ecu_spec = specs
    tags = [claim.tag for claim in state.claims]
    codec = command.codec
    own = sent_by(codec, "Command")
    sequence = RunSequence(codec, s.ecu_rate_hz, own, strict=_strict(opts, s))
    with RunBus(state.take_bus(), tags[0], sequence) as bus, ExitStack() as stack:
        state.run_bus = bus
        if s.bus_faults:
            injector = Injector(s.bus_faults, s.ecu_rate_hz, seed, command.codec)
            state.bus_fault_events = injector.events
            clock = WallTicks(s.ecu_rate_hz) if opts.mode == "realtime" else SensorTicks()
            plant_side = stack.enter_context(RunBus(open_bus(spec), tags[0]))
            ecu_side = stack.enter_context(RunBus(open_bus(ecu_spec), tags[-1]))
            bridge = stack.enter_context(Bridge(plant_side, ecu_side, injector, ticks=clock))
            state.bridge_errors = bridge.errors
            state.ecu_heard = bridge.ecu_side_heard  # the ECU's frames before the injector
        # once both are ready (each listening on the bus; the plant built and waiting for its
        # start file, keeping what it hears meanwhile), the frames due before tick 0 go out and
        # the plant sends tick 0: in real time too, the ECU is armed only when the engine's
        # frames are coming
        failed = _wait_until_ready(opts.out_dir, state.children)
        if failed is not None:
            state.status, state.abort_reason = "aborted", failed
            return
        _drain(bus)
        send = bus_sender(bus, DriverStats())
        command.start(send)
        _start_file(opts.out_dir).touch()
        state.nodes_up = time.perf_counter()
        _listen(
            bus,
            command,
            state,
            send,
            realtime=opts.mode == "realtime",
            period=1.0 / s.ecu_rate_hz,
            turns=_strict(opts, s),
        )


def _wait_until_ready(out_dir: Path, children: dict[str, subprocess.Popen]) -> str | None:
    """Wait until every node process has said it is ready; else why the run cannot begin, naming
    the node (:class:`sil.watchdog.StartWatch`: it exited, is stopped, makes no progress or is
    not ready within the overall limit)."""
    watch = StartWatch(time.monotonic())
    while True:
        ready = {name: _ready_file(out_dir, name).exists() for name in children}
        if all(ready.values()):
            return None
        nodes = {n: Starting(p.pid, p.poll(), ready[n]) for n, p in children.items()}
        failed = watch.check(nodes, time.monotonic())
        if failed is not None:
            name, why = failed
            said = "" if why.startswith("stopped") else _last_line(out_dir / f"{name}.log")
            return f"{name} process did not come up: {why}{f': {said}' if said else ''} " + (
                f"(see {name}.log)"
            )
        time.sleep(READY_POLL_S)


def _last_line(log: Path) -> str:
    """The last line a node wrote to its log (why it stopped), or ""."""
    try:
        lines = log.read_text(errors="replace").split("\n")
    except OSError:
        return ""
    return next((line.strip() for line in reversed(lines) if line.strip()), "")


def _drain(bus: can.BusABC) -> None:
    """Drop the frames queued before the run starts: an ECU on its own clock (real time, or
    past its guard time while the plant builds) talks before there is an engine."""
    receive = bus_batch_receiver(bus)
    while receive(0.0):
        pass


def _stats_file(out_dir: Path, node: str) -> Path:
    """Where a node process leaves its run summary (taken into summary.json, then removed)."""
    return out_dir / f".{node}-stats.json"


def _node_stats(out_dir: Path) -> dict[str, dict]:
    """The node processes' own summaries: frames, timeouts; in real time jitter and overruns."""
    stats = {}
    for node in ("ecu", "plant"):
        path = _stats_file(out_dir, node)
        try:
            stats[node] = json.loads(path.read_text())
        except (OSError, ValueError):
            continue  # a node that died mid-run leaves none
        finally:
            path.unlink(missing_ok=True)
    return stats


def _ecu_side(opts: RunOptions, spec: BusSpec) -> BusSpec:
    """The ECU's bus behind the fault bridge: ``--ecu-bus``, else a second loopback bus."""
    if opts.ecu_bus:
        ecu_spec = parse_spec(opts.ecu_bus)
    elif spec.interface == "udp":
        ecu_spec = unique_udp_spec()
    else:
        raise BusSpecError(
            f"bus faults on {spec} need a second bus for the ECU behind the fault bridge: "
            "give it with --ecu-bus (for example socketcan:vcan1)"
        )
    if ecu_spec == spec:
        raise BusSpecError(f"--ecu-bus {ecu_spec} is the run's bus: the bridge needs two buses")
    return ecu_spec


def _listen(
    bus: can.BusABC,
    command: CommandNode,
    state: RunState,
    send,
    *,
    realtime: bool,
    period: float,
    turns: bool = False,
) -> None:
    """The command node's loop: frames in (all those queued at each read), and a watch on the
    node processes. One that exits aborts the run; so does one that falls silent: with
    ``turns`` (lockstep without bus faults) the node whose turn it is, once /proc shows it dead
    (:class:`sil.watchdog.TurnWatch`; a slow one is waited for), its peer then told and
    recorded on its own clock for PEER_GRACE_S; else one that sends nothing for
    ``watchdog.SILENCE_S``, its peer having run on its own clock since its guard time."""
    died_at = None
    receive = bus_batch_receiver(bus)
    paced = not realtime and getattr(bus, "recv_frames", None) is not None
    start = time.monotonic()
    next_period = next_check = start
    dog = Watchdog(command.codec.messages, start)
    seen: dict[int, float] = {}  # frame ID -> when last heard
    watch = _TurnState(state.children, start) if turns else None
    state.turn_watch = watch.watch if watch is not None else None
    grace = PEER_GRACE_S if turns else GRACE_S
    drained = False  # the last read found no frame queued: what was heard is up to date
    while not command.finished:
        now = time.monotonic()
        if realtime and now >= next_period:
            command.on_period(send, now - start)
            next_period += period
            continue
        if now >= next_check:
            next_check = now + 0.2
            if died_at is None:
                died_at = _node_exited(state, now)
                if died_at is None and watch is None:
                    if (silent := _silent(dog, seen, state, now)) is not None:
                        state.status, state.abort_reason = "aborted", silent
                        return  # its peer has run on its own clock since its guard time
                elif died_at is None and drained and (dead := watch.dead(now)) is not None:
                    state.status, state.abort_reason = "aborted", dead
                    died_at = now
                if died_at is not None and watch is not None and state.status == "aborted":
                    _peer_lost(state, bus)
            elif now - died_at > (grace if state.status == "aborted" else GRACE_S):
                if state.status != "aborted":  # it ended cleanly, and the run's end never came
                    state.status, state.abort_reason = "aborted", _ended_early(state, command)
                return
        frames = receive(min(0.05, next_period - now) if realtime else 0.05)
        drained = not frames
        for got in frames:
            if type(got) is not tuple:
                if unusable(got) is not None:
                    continue
                got = (got.arbitration_id, got.data)
            seen[got[0]] = now
            if watch is not None:
                watch.heard(got[0], now)
            wall_s = time.monotonic() - start if realtime else None
            command.on_frame(got[0], got[1], send, wall_s=wall_s)
            if command.finished:
                return
        if frames and paced:
            time.sleep(LOCKSTEP_READ_S)


class _TurnState:
    """Whose turn it is in lockstep, as the command node hears the run (the plant's after
    EcuActuator(k), the ECU's after PlantSensors(k)), and since when that node has been silent;
    :class:`sil.watchdog.TurnWatch` judges it."""

    def __init__(self, children: dict[str, subprocess.Popen], now: float) -> None:
        self.watch = TurnWatch({name: proc.pid for name, proc in children.items()})
        self.node = "plant"  # tick 0 is the plant's
        self.since = now
        self._of = {i: "plant" for i in PLANT_IDS} | {i: "ecu" for i in ECU_IDS}

    def heard(self, frame_id: int, now: float) -> None:
        if frame_id == SENSORS:
            self.node, self.since = "ecu", now
        elif frame_id == ACTUATOR:
            self.node, self.since = "plant", now
        elif self._of.get(frame_id) == self.node:
            self.since = now

    def dead(self, now: float) -> str | None:
        return self.watch.check(self.node, self.since, now)


def _peer_lost(state: RunState, bus: RunBus) -> None:
    """A node is dead: the others are told (they run on their own clocks from now on, and
    show their reaction to the loss), and the command node's bus stops holding the run to its
    lockstep sequence."""
    for proc in state.children.values():
        if proc.poll() is None:
            try:
                proc.send_signal(PEER_LOST_SIGNAL)
            except ProcessLookupError:
                pass
    bus.relax()


def _node_exited(state: RunState, now: float) -> float | None:
    """``now`` if a node process has exited, else None. One that failed marks the run aborted;
    one that ended cleanly (code 0: its last tick done) does not yet: the command node, behind
    it on a loaded machine, may still have its last frames to read (``_ended_early``)."""
    for name, proc in state.children.items():
        code = proc.poll()
        if code is not None:
            if code != 0:
                state.status = "aborted"
                state.abort_reason = f"{name} process exited with code {code} mid-run"
            return now
    return None


def _ended_early(state: RunState, command: CommandNode) -> str:
    """Why the run aborts when a node that ended cleanly left it short of its last tick."""
    ended = [n for n, p in state.children.items() if p.poll() == 0] or ["a node"]
    return (
        f"{ended[0]} process ended (code 0) before the ECU answered the run's last tick "
        f"(answered {command.recorder.tick} of {command.last_tick + 1} ticks within "
        f"{GRACE_S:g} s)"
    )


def _silent(dog: Watchdog, seen: dict[int, float], state: RunState, now: float) -> str | None:
    """Why the run must end because a node fell silent, or None."""
    if state.ecu_heard is not None:  # through the bridge: what the ECU sent, before any fault
        # (only the ECU's IDs: the bridge may hear its own frames to the ECU's side)
        ecu = {i: at for i, at in dict(state.ecu_heard).items() if dog.node_of.get(i) == "ECU"}
        seen = {**seen, **{i: max(at, seen.get(i, at)) for i, at in ecu.items()}}
    return dog.silent(seen, now)


def _isolation(state: RunState) -> dict:
    """On a bus: the run's RunId and tag, and the other runs' frames it heard and dropped."""
    if state.run_bus is None:
        return {}
    return {"run_id": state.run_id, **state.run_bus.stats()}


def demand_warnings(s: Scenario, commands: np.ndarray, params: EcuParams) -> list[str]:
    """What the ECU will not fly as asked: speed demands outside its idle..maximum range, which
    it holds at the nearer end."""
    out = []
    top, bottom = float(np.max(commands)), float(np.min(commands))
    if top > params.demand_max_pct + 1e-9:
        out.append(
            f"{s.name}: command: demand reaches {top:g} %N, over the ECU's demand_max_pct "
            f"{params.demand_max_pct:g}: the ECU holds it there"
        )
    if bottom < params.idle_pct - 1e-9:
        out.append(
            f"{s.name}: command: demand falls to {bottom:g} %N, under the ECU's idle_pct "
            f"{params.idle_pct:g}: the ECU holds it there"
        )
    return out


def _egt_limit_k(s: Scenario) -> float:
    return preset(s.controller.preset or "default", **s.controller.params).egt_limit_k


def _transient(s: Scenario, trace: dict) -> dict:
    """metrics.transient with the ECU's EGT limit and the surge line of the scenario's engine."""
    p = s.plant
    margin = metrics.surge_margin_at(
        p.ambient_temperature_K, p.ambient_pressure_Pa, p.flight_speed_m_s
    )
    return metrics.transient(trace, _egt_limit_k(s), margin)


def _finish(
    opts: RunOptions,
    s: Scenario,
    seed: int,
    recorder: Recorder | RecorderProcess,
    command: CommandNode,
    state: RunState,
    wall: float,
) -> dict:
    totals = recorder.totals()
    sim_time = totals["tick"] / s.ecu_rate_hz
    period = 1.0 / s.ecu_rate_hz
    trace = None
    try:
        trace = metrics.load_trace(opts.out_dir / "trace.csv")
    except (OSError, ValueError) as exc:  # a recorder that died mid-run: the rest is reported
        state.status = "aborted"
        state.abort_reason = state.abort_reason or f"trace.csv cannot be read: {exc}"
    summary = {
        "status": state.status,
        "abort_reason": state.abort_reason,
        "scenario": s.name,
        "mode": opts.mode,
        "bus": state.bus,
        **_isolation(state),
        **({"inproc_loop": state.loop} if state.loop else {}),
        **({"ecu_bus": state.ecu_bus} if state.ecu_bus else {}),
        "seed": seed,
        "run": {k: v for k, v in state.record.items() if k != "format"},
        **({"warnings": state.warnings} if state.warnings else {}),
        "sim_time_s": sim_time,
        "wall_time_s": wall,
        "realtime_factor": sim_time / wall if wall > 0 else math.nan,
        # on a bus: what of wall_time_s went to starting the node processes (before tick 0)
        **({"startup_s": state.nodes_up - state.started} if state.nodes_up else {}),
        "frames": totals["frames"],
        "bus_load_pct": bus_load_pct(totals["bits"], sim_time),
        "missed_ticks": totals["missed_ticks"],
        **(metrics.summarize(trace, period, REPORTED_FAULTS) if trace is not None else {}),
        **(_transient(s, trace) if trace is not None and len(trace["time"]) > 1 else {}),
        **(metrics.start_stop(trace) if trace is not None else {}),
        "faults_injected": [{"time_s": i["tick"] / s.ecu_rate_hz, **i} for i in command.injected],
        "bus_faults_injected": state.bus_fault_events,
        **({"bridge_errors": state.bridge_errors} if state.bridge_errors else {}),
        "e2e": {m: c for m, c in totals["e2e"].items() if set(c) - {"OK"}},
        **({"nodes": nodes} if (nodes := _node_stats(opts.out_dir)) else {}),
        # the image's own figures (--ecu-impl pil), taken out of the ECU node's
        **({"pil": pil} if (pil := nodes.get("ecu", {}).pop("pil", None)) else {}),
        "unknown_ids": {f"0x{k:X}": v for k, v in totals["unknown_ids"].items()},
        "wrong_length": {f"0x{k:X}": v for k, v in totals["wrong_length"].items()},
    }
    if state.status == "completed" and totals["tick"] < len(command.commands):
        summary["status"] = "aborted"
        summary["abort_reason"] = summary["abort_reason"] or "the run ended early"
    if state.turn_watch is not None and state.turn_watch.looked:
        summary["slow_turns"] = state.turn_watch.looked
    _other_senders(summary)
    for name in ("ecu", "plant"):
        log = opts.out_dir / f"{name}.log"
        if log.exists():
            summary[f"{name}_log"] = log.name
    tick0 = state.started_wall + (state.nodes_up - state.started if state.nodes_up else 0.0)
    for fmt in opts.log_formats:
        try:
            convert(opts.out_dir / "can.log", fmt, start_s=tick0)
        except results.WriteError as exc:
            state.write_errors.append(str(exc))
    if opts.plots and trace is not None:
        summary["plots"] = _plots(opts, s, trace, state)
    _write_summary(opts.out_dir, summary, state)
    for path in _handshake_files(opts.out_dir):
        path.unlink(missing_ok=True)
    return results.status_first(summary)


def _other_senders(summary: dict) -> None:
    """Another sender's frames on the run's bus (heard by the recorder or a node): a run they
    disturbed (aborted, or with missed ticks) is aborted saying so first; an undisturbed one
    warns of them."""
    counts = [summary.get("other_sender_frames", 0)]
    ids = set(summary.get("other_sender_ids", {}))
    firsts = [f"run: {summary['other_sender_first'][0]}"] if "other_sender_first" in summary else []
    for name, node in summary.get("nodes", {}).items():
        counts.append(node.get("other_sender_frames", 0))
        ids |= set(node.get("other_sender_ids", {}))
        if "other_sender_first" in node:
            firsts.append(f"{name}: {node['other_sender_first'][0]}")
    frames = max(counts)
    if not frames:
        return
    listed = sorted(ids, key=lambda i: int(i, 16))
    shown = ", ".join(listed[:6]) + (", ..." if len(listed) > 6 else "")
    first = f"; first dropped by {firsts[0]}" if firsts else ""
    said = (
        f"foreign frames on the bus: {frames:,} from another sender (IDs {shown}{first}) — "
        "the run's bus is shared"
    )
    if summary["status"] != "completed" or summary["missed_ticks"]:
        why = summary["abort_reason"] or f"{summary['missed_ticks']} missed ticks"
        summary["status"] = "aborted"
        summary["abort_reason"] = f"{said} ({why})"
    else:
        warning = f"{said}; they were left out of the run"
        summary.setdefault("warnings", []).append(warning)
        print(f"sil run: warning: {warning}", file=sys.stderr)


def _plots(opts: RunOptions, s: Scenario, trace: dict, state: RunState) -> list[str]:
    """Write the run's plots; the names written (a plot that cannot be written is noted in
    ``state.write_errors``, and the rest are not tried)."""
    from sil import plots  # matplotlib: only when plotting (campaign runs do not)

    title = f"{s.name} ({s.controller.kind}, {s.plant.model} plant)"
    limit = _egt_limit_k(s)
    try:
        return [
            p.name for p in plots.plot_run(trace, opts.out_dir, title, s.controller.kind, limit)
        ]
    except results.WriteError as exc:
        state.write_errors.append(str(exc))
        return [name for name in results.PLOTS if (opts.out_dir / name).is_file()]


def _write_summary(out_dir: Path, summary: dict, state: RunState) -> None:
    """The final summary; a run whose results could not all be written is aborted, naming the
    first file, and lists what it kept. If even the summary cannot be written, a compact one
    goes over the ``running`` one in its space; the returned summary says why either way."""
    if state.write_errors:
        _not_all_written(out_dir, summary, state)
    try:
        results.write_summary(out_dir, summary)
        return
    except results.WriteError as exc:
        state.write_errors.append(str(exc))
    _not_all_written(out_dir, summary, state)
    keys = ("status", "abort_reason", "scenario", "write_errors", "kept")
    try:  # the least that says what happened, in the room the running summary had
        results.write_summary_in_place(out_dir, {k: summary[k] for k in keys})
    except results.WriteError:
        summary["kept"] = [name for name in summary["kept"] if name != results.SUMMARY]


def _not_all_written(out_dir: Path, summary: dict, state: RunState) -> None:
    summary["status"] = "aborted"
    summary["abort_reason"] = summary["abort_reason"] or state.write_errors[0]
    summary["write_errors"] = list(state.write_errors)
    summary["kept"] = sorted({*results.kept(out_dir), results.SUMMARY})
