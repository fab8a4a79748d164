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
import os
import sys
import time
from pathlib import Path

from ecu import commissioning
from ecu.firmware_params import compile_params
from ecu.params import preset
from ecu.port.node import CEcuNode
from protocol.bus import open_bus
from protocol.codec import Codec
from protocol.run_tag import claim_tag
from sil.record import results
from sil.record.recorder import Recorder
from sil.run import run_folder, run_record
from sil.run.command_node import CommandNode
from sil.run.config import (
    RunOptions,
    build_plant,
    bus_spec,
    check_ecu_impl,
    demand_warnings,
    ecu_args,
    ecu_overrides,
    ecu_params,
    ecu_side,
    handshake_files,
    plant_args,
)
from sil.run.inproc import fly, inproc_nodes
from sil.run.processes import (
    run_on_bus,
    spawn,
    stop,
)
from sil.run.recorder_process import RecorderFailed, RecorderProcess
from sil.run.state import RunState
from sil.run.summary import (
    finish,
)
from sil.run.watchdog import interrupt_reason
from sil.scenario import Scenario, profiles


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

    Every input (the scenario and commissioning files, the ECU parameters and what its
    implementation needs, the bus, ``--out``) is checked before the run folder is touched; a
    refusal raises ValueError (BusSpecError, :class:`~sil.run.run_folder.FolderError`) and leaves
    the folder as it was. The folder is then made and locked for the run's time
    (:class:`~sil.run.run_folder.FolderLock`), cleared of an earlier run's files and marked
    running. A result that cannot be written raises
    :class:`~sil.record.results.WriteError` before the run began; once it flew, the run is aborted
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
    in process, an ECU implementation whose pieces are missing (the emulator, a compiler: they
    are built here), a bus that cannot be opened (it is opened here, for the run), a
    commissioning file the ECU would refuse, ECU parameters it would refuse (checked at the
    preset's trim; the run's own trim is checked again once the plant is built)."""
    if opts.mode == "inproc" and opts.ecu_impl == "pil":
        raise ValueError("--ecu-impl pil runs the image on a bus: use --mode lockstep or "
                         "realtime")  # fmt: skip
    check_ecu_impl(opts)
    nominal = {
        k: v for k, v in ecu_overrides(s, 0.0, 0.0).items() if k not in ("trim_v", "entry_v")
    }
    params = preset(s.controller.preset or "default", **nominal)
    if opts.commission is not None:
        params = commissioning.commission(params, opts.commission)
    compile_params(params)
    if opts.mode == "inproc":
        return
    spec = bus_spec(opts)
    ecu_spec = ecu_side(opts, spec) if s.bus_faults else spec
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
        stop(state.children)
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
        for path in handshake_files(opts.out_dir):
            path.unlink(missing_ok=True)
        ticks = profiles.tick_count(s.duration_s, s.ecu_rate_hz) + 1  # 0 .. last: len(commands)
        state.children["plant"] = spawn(
            "plant", plant_args(opts, s, seed, spec, state.claims[0].tag, ticks), opts.out_dir
        )
    plant = build_plant(s, seed)
    params = ecu_params(s, plant)
    if opts.commission is not None:
        params = commissioning.commission(params, opts.commission)
    compile_params(params)  # refuse bad overrides before anything starts
    if ecu_spec is not None:
        argv = ecu_args(opts, s, params, ecu_spec, state.claims[-1].tag)
        state.children["ecu"] = spawn("ecu", argv, opts.out_dir)
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
        built = inproc_nodes(opts, s, params, plant)
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
            fly(s, seed, command, built, state, progress)
        else:
            assert spec is not None and ecu_spec is not None
            run_on_bus(opts, s, seed, (spec, ecu_spec), command, state)
    except KeyboardInterrupt as exc:
        state.status, state.abort_reason = "aborted", interrupt_reason(exc)
    except (RecorderFailed, results.WriteError) as exc:  # the recorder's files, a full disk
        _recording_failed(state, exc)
    finally:
        stop(state.children)
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
    return finish(opts, s, seed, recorder, command, state, wall)


def _recording_failed(state: RunState, exc: RecorderFailed | results.WriteError) -> None:
    """The recorder failed (its process died, or a file could not be written): the run is
    aborted with the first such reason."""
    state.status = "aborted"
    state.abort_reason = state.abort_reason or str(exc)
    if isinstance(exc, results.WriteError) or getattr(exc, "write_error", False):
        state.write_errors.append(str(exc))
