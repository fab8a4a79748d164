"""The in-process run with the C ECU as one compiled loop: ``--mode inproc --ecu-impl c``.

Through :class:`protocol.node.InProcessBus`, a tick with the C ECU costs about three times the
plant's compiled period and the C tick together: the rest is the Python that carries four to
five frames a tick between the nodes. Here one numba function does that work for many ticks at
a time, with the same nodes and in the same order:

- the same FIFO of frames and the same routes (the command node hears every frame but its own,
  the ECU its ``frame_ids``, then the plant its own), stopping where InProcessBus stops: once
  the ECU has answered the last tick;
- the command node: what it sends depends only on the tick, so its frames are packed
  beforehand by the command node itself (:meth:`CommandNode.frames_at`), and played here on
  each PlantSensors frame as it would play them; the frames it records go into arrays;
- the ECU: the C node (``ecu/port/ecu_node.c``, the twin of ecu/node.py) called by its address;
- the plant: the compiled twin of the plant node (:func:`plant.node_compiled.actuator_compiled`,
  :func:`plant.node_compiled.advance_compiled`).

It returns to Python for what stays there: a FaultInject or EcuStarter frame for the plant, the
Python part of a plant period (faults falling due, noise blocks: :meth:`PlantNode.python_part`),
and a full chunk of recorded frames, which go to the recorder in whole ticks
(``Recorder.record_ticks``; the first tick frame by frame, as the command node records). The
files are the run's through InProcessBus with the C ECU, byte for byte
(tests/sil/test_compiled_loop.py).
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from ecu.port.node import CEcuNode, frame_fn_address, node_library
from plant.frames import DUE_ANALOG, DUE_TRUTH
from plant.jit import PLANT_DIR, keep_cache_fresh
from plant.node import PlantNode
from plant.node_compiled import (
    NF_SIZE,
    NS_FLAGS,
    NS_SIZE,
    actuator_compiled,
    advance_compiled,
    python_due,
)
from plant.periphery import OUT, OUT_FIELDS
from protocol.lockstep import TICK_MODULO
from sil.record.ticks import ACTUATOR, SENSORS
from sil.run.command_node import CommandNode

_HERE = Path(__file__).resolve()
# the loop links the plant's compiled functions: its cached machine code goes with their sources
keep_cache_fresh(
    _HERE.parent / "__pycache__",
    _HERE.parent / "__pycache__" / "compiled_loop.numba-sources.sha256",
    "compiled_loop.*",
    [_HERE, *sorted(PLANT_DIR.glob("*.py")), *sorted((PLANT_DIR.parent / "protocol").glob("*.py"))],
)

CMD, ECU, PLANT = 0, 1, 2  # where a frame comes from: the nodes in InProcessBus order
QUEUE = 64  # frames in flight (a tick has at most a dozen)
CHUNK_FRAMES = 8192  # frames recorded before the loop hands them to the recorder (~1800 ticks)
FRAME_BYTES = 12  # ecu_can_frame_t: uint32 id, 8 data bytes
NODE_OUT = 4  # ECU_NODE_MAX_OUT
# the loop's state (int64 slots)
(
    L_HEAD,  # queue: next frame to deliver
    L_TAIL,  # queue: next free place
    L_OUT,  # frames recorded in the chunk
    L_BOUNDARY,  # frames recorded in the chunk up to its last EcuActuator (whole ticks)
    L_LIMIT,  # recorded frames at which the loop returns the chunk
    L_SENSOR_LAST,  # the sensor ticks' unwrapper (TickUnwrapper.last)
    L_LATEST,  # the newest sensor tick (full)
    L_ANSWERED,  # ticks the ECU answered (EcuActuator frames recorded)
    L_LAST_TICK,  # the scenario's last tick
    L_LEAD,  # the command node's lead and demand period, in ticks
    L_EVERY,
    L_PLAYED,  # the last tick whose command frames were sent
    L_FINISHED,  # the command node is finished
    L_RESUME,  # the plant's advance waits for its Python part
    L_FAULT_SLOT,  # queue place of the FaultInject or EcuStarter frame handed to Python
    L_SIZE,
) = range(16)
# the frame IDs the loop tells apart
I_SENSORS, I_ACTUATOR, I_FAULT, I_ECU, I_PLANT = 0, 1, 2, 3, 6  # I_ECU: 3, I_PLANT: 5 IDs
I_STARTER = 11  # EcuStarter
# why the loop returned (PLANT_FRAME: a FaultInject or EcuStarter frame for the plant node)
DONE, CHUNK, PLANT_FRAME, PLANT_PYTHON, IDLE = range(5)
# the plant's truth kept per tick answered (CompiledLoop.truth): true speed %N, EGT K, P3 Pa and
# thrust N from its outputs, then its flags (plant.flags)
TRUTH_FIELDS = ("n_pct", "egt_true_k", "p3_pa", "thrust_n")
TRUTH = tuple(OUT + OUT_FIELDS.index(name) for name in TRUTH_FIELDS)
TRUTH_COLUMNS = len(TRUTH) + 1


@intrinsic
def _call_node(typingctx, fn, node, frame_id, data, out):  # noqa: ANN001, ARG001
    """``ecu_node_frame(node, frame_id, data, out)`` at address ``fn`` (addresses as intp)."""
    sig = types.int32(types.intp, types.intp, types.uint32, types.intp, types.intp)

    def codegen(context, builder, signature, args):  # noqa: ANN001, ARG001
        byte_ptr = ir.IntType(8).as_pointer()
        fn_type = ir.FunctionType(ir.IntType(32), [byte_ptr, ir.IntType(32), byte_ptr, byte_ptr])
        function = builder.inttoptr(args[0], fn_type.as_pointer())
        pointers = [builder.inttoptr(args[i], byte_ptr) for i in (1, 3, 4)]
        return builder.call(function, [pointers[0], args[2], pointers[1], pointers[2]])

    return sig, codegen


@njit(cache=True, inline="always")
def _push(ls, q_id, q_origin, q_data, origin, frame_id, data):  # noqa: ANN001
    tail = ls[L_TAIL]
    if tail - ls[L_HEAD] >= QUEUE - 1:  # (the place of the frame being delivered stays)
        raise RuntimeError("compiled loop: more frames in flight than the queue holds")
    slot = tail % QUEUE
    q_id[slot] = frame_id
    q_origin[slot] = origin
    q_data[slot, :] = data
    ls[L_TAIL] = tail + 1


@njit(cache=True, inline="always")
def _record(ls, out_id, out_data, frame_id, data):  # noqa: ANN001
    n = ls[L_OUT]
    out_id[n] = frame_id
    out_data[n, :] = data
    ls[L_OUT] = n + 1


@njit(cache=True, nogil=True)  # (the recorder's feeder thread sends meanwhile)
def run_frames(
    ls, q_id, q_origin, q_data, out_id, out_data, plan_first, plan_id, plan_data, ids,
    ecu_fn, ecu_node, ecu_out, s, tables, ns, nf, lay, buf, truth,
):  # fmt: skip  # noqa: ANN001, ANN201
    """Deliver frames (InProcessBus.run) until the run is done, the chunk is full or Python
    has something to do; returns why (DONE, CHUNK, PLANT_FRAME, PLANT_PYTHON, IDLE)."""
    if ls[L_RESUME]:
        ls[L_RESUME] = 0
        _plant_advance(ls, q_id, q_origin, q_data, ids, s, tables, ns, nf, lay, buf)
    while ls[L_HEAD] != ls[L_TAIL]:
        if ls[L_FINISHED]:
            return DONE
        if ls[L_OUT] >= ls[L_LIMIT]:
            return CHUNK
        slot = ls[L_HEAD] % QUEUE
        ls[L_HEAD] += 1
        frame_id = q_id[slot]
        origin = q_origin[slot]
        data = q_data[slot]
        if origin != CMD:  # CommandNode.on_frame: recorded; on PlantSensors, its frames sent
            _record(ls, out_id, out_data, frame_id, data)
            if frame_id == ids[I_SENSORS]:
                _on_sensors(ls, q_id, q_origin, q_data, out_id, out_data, plan_first, plan_id,
                            plan_data, data[2] | np.int64(data[3]) << 8)  # fmt: skip
            elif frame_id == ids[I_ACTUATOR]:
                k = ls[L_ANSWERED]
                if k < len(truth):  # the plant as it is when the ECU answers tick k
                    for j in range(len(TRUTH)):
                        truth[k, j] = s[TRUTH[j]]
                    truth[k, len(TRUTH)] = ns[NS_FLAGS]
                ls[L_ANSWERED] = k + 1
                ls[L_BOUNDARY] = ls[L_OUT]
                if ls[L_ANSWERED] > ls[L_LAST_TICK]:
                    ls[L_FINISHED] = 1
        if origin != ECU and (
            frame_id == ids[I_ECU] or frame_id == ids[I_ECU + 1] or frame_id == ids[I_ECU + 2]
        ):
            at = q_data.ctypes.data + slot * 8
            n = _call_node(ecu_fn, ecu_node, np.uint32(frame_id), at, ecu_out.ctypes.data)
            for j in range(n):
                f = j * FRAME_BYTES
                out_frame = np.int64(0)
                for b in range(4):  # uint32 little-endian
                    out_frame |= np.int64(ecu_out[f + b]) << (8 * b)
                _push(ls, q_id, q_origin, q_data, ECU, out_frame, ecu_out[f + 4 : f + FRAME_BYTES])
        if origin != PLANT:
            if frame_id == ids[I_FAULT] or frame_id == ids[I_STARTER]:
                ls[L_FAULT_SLOT] = slot
                return PLANT_FRAME
            if frame_id == ids[I_ACTUATOR] and actuator_compiled(ns, nf, lay, data):
                if python_due(ns, nf):
                    ls[L_RESUME] = 1
                    return PLANT_PYTHON
                _plant_advance(ls, q_id, q_origin, q_data, ids, s, tables, ns, nf, lay, buf)
    return DONE if ls[L_FINISHED] else IDLE


@njit(cache=True, inline="always")
def _on_sensors(ls, q_id, q_origin, q_data, out_id, out_data, plan_first, plan_id, plan_data,
                tick16):  # fmt: skip  # noqa: ANN001
    """The newest sensor tick (TickUnwrapper), and the command node's frames for the tick one
    lead ahead, when it is a demand tick of the scenario: recorded as sent, then queued."""
    last = ls[L_SENSOR_LAST]
    if last < 0:
        tick = tick16
    else:
        delta = (tick16 - last) % TICK_MODULO
        if delta >= TICK_MODULO // 2:
            delta -= TICK_MODULO
        tick = last + delta
    ls[L_SENSOR_LAST] = tick
    if tick > ls[L_LATEST]:
        ls[L_LATEST] = tick
    target = ls[L_LATEST] + ls[L_LEAD]
    if target % ls[L_EVERY] == 0 and target <= ls[L_LAST_TICK]:
        k = target // ls[L_EVERY]
        for m in range(plan_first[k], plan_first[k + 1]):
            _record(ls, out_id, out_data, plan_id[m], plan_data[m])
            _push(ls, q_id, q_origin, q_data, CMD, plan_id[m], plan_data[m])
        ls[L_PLAYED] = target


@njit(cache=True, inline="always")
def _plant_advance(ls, q_id, q_origin, q_data, ids, s, tables, ns, nf, lay, buf):  # noqa: ANN001
    """The plant's period and its frames of the next tick, queued (PlantNode._send_tick)."""
    due = advance_compiled(s, tables, ns, nf, lay, buf)
    if due & DUE_TRUTH:
        _push(ls, q_id, q_origin, q_data, PLANT, ids[I_PLANT], buf[0:8])
        _push(ls, q_id, q_origin, q_data, PLANT, ids[I_PLANT + 1], buf[8:16])
        _push(ls, q_id, q_origin, q_data, PLANT, ids[I_PLANT + 2], buf[16:24])
    if due & DUE_ANALOG:
        _push(ls, q_id, q_origin, q_data, PLANT, ids[I_PLANT + 3], buf[24:32])
    _push(ls, q_id, q_origin, q_data, PLANT, ids[I_PLANT + 4], buf[32:40])


class Recording(Protocol):
    """What the loop hands the frames to: the Recorder, the RecorderProcess, a campaign's Probe."""

    def record(
        self, frame_id: int, data: bytes | bytearray, wall_s: float | None = None
    ) -> None: ...

    def commands_sent(self) -> None: ...

    def record_ticks(self, frame_ids: np.ndarray, payload: np.ndarray) -> None: ...


def compile_loop() -> None:
    """Compile :func:`run_frames` now, or load it from numba's cache: a set-up step, so that a
    run does not spend its first call on it. (An empty queue: it returns at once.)"""
    ints, frames = np.zeros(1, np.int64), np.zeros((1, 8), np.uint8)
    floats, data = np.zeros(1), np.zeros(1, np.uint8)
    ls = np.zeros(L_SIZE, np.int64)
    run_frames(
        ls, ints, ints, frames, ints, frames, ints, ints, frames, ints, 0, 0, data, floats, floats,
        ints, floats, ints, data, np.zeros((1, 2)),
    )  # fmt: skip


class CompiledLoop:
    """The three nodes of an in-process run with the C ECU, driven by :func:`run_frames`.

    ``command`` plays the scenario (its frames are planned from it; its ``injected`` and
    ``finished`` are kept as a run through InProcessBus leaves them), ``ecu`` is the C node,
    ``plant`` the plant node (``plant.compiled()``), ``recorder`` takes the frames.
    """

    def __init__(
        self,
        command: CommandNode,
        ecu: CEcuNode,
        plant: PlantNode,
        recorder: Recording,
    ) -> None:
        if not plant.compiled():
            raise ValueError(f"{type(plant.plant).__name__}: the plant node has no compiled twin")
        if ctypes.sizeof(node_library().frame_t) != FRAME_BYTES:
            raise ValueError("ecu_can_frame_t is not the 12 bytes the compiled loop reads")
        self.command, self.ecu, self.plant, self.recorder = command, ecu, plant, recorder
        # per tick answered, the plant's truth (TRUTH_FIELDS, flags) when the ECU answered it:
        # what a campaign's probe reads from the plant in process (sil/campaign/probe.py)
        self.truth = np.full((command.last_tick + 1, TRUTH_COLUMNS), np.nan)
        self._first_tick = True  # the frames up to the first EcuActuator go one by one
        self._one_by_one = False  # every frame from now on (after a chunk of no whole tick)
        self._own_ids = (command.demand.frame_id, command.fault_msg.frame_id)

    def _plan(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The command node's frames at every demand tick, in sending order: (first frame of
        each demand tick, and one past the last), IDs, payloads."""
        command = self.command
        first = [0]
        frame_ids: list[int] = []
        payload = bytearray()
        for tick in command.demand_ticks():
            for frame_id, data in command.frames_at(tick):
                frame_ids.append(frame_id)
                payload += data
            first.append(len(frame_ids))
        return (
            np.array(first, np.int64),
            np.array(frame_ids, np.int64),
            np.frombuffer(bytes(payload), np.uint8).reshape(-1, 8).copy(),
        )

    def run(self, progress: Callable[[int], None] | None = None) -> None:
        """Start the nodes and deliver frames until the command node is finished (or the frames
        run out); every frame recorded reaches the recorder, also on an exception."""
        command, plant = self.command, self.plant
        plan_first, plan_id, plan_data = self._plan()
        per_tick = int(np.diff(plan_first).max(initial=0))
        limit = CHUNK_FRAMES
        out_id = np.zeros(limit + per_tick + 16, np.int64)
        out_data = np.zeros((len(out_id), 8), np.uint8)
        q_id = np.zeros(QUEUE, np.int64)
        q_origin = np.zeros(QUEUE, np.int64)
        q_data = np.zeros((QUEUE, 8), np.uint8)
        ls = np.zeros(L_SIZE, np.int64)
        ls[L_LIMIT] = limit
        ls[L_SENSOR_LAST] = ls[L_LATEST] = ls[L_PLAYED] = -1
        ls[L_LAST_TICK], ls[L_LEAD], ls[L_EVERY] = command.last_tick, command.lead, command.every
        ids = np.array(
            [
                SENSORS,
                ACTUATOR,
                plant._fault_id,
                *self.ecu.frame_ids,
                *plant._ids,
                plant._starter_id,
            ],
            np.int64,
        )
        ecu_out = np.zeros(NODE_OUT * FRAME_BYTES, np.uint8)
        ns, nf = np.zeros(NS_SIZE, np.int64), np.zeros(NF_SIZE, np.float64)
        state = plant.plant._s  # (shared, as the frames' layout and buffer)
        tables = plant.plant._tables

        def queue(origin: int, frame_id: int, data: bytes | bytearray) -> None:
            slot = ls[L_TAIL] % QUEUE
            q_id[slot], q_origin[slot] = frame_id, origin
            q_data[slot] = np.frombuffer(bytes(data), np.uint8)
            ls[L_TAIL] += 1

        # InProcessBus starts the nodes in order: the command node's first demands (recorded as
        # sent), the ECU (nothing to send), the plant's tick 0
        for tick in range(0, min(command.lead, command.last_tick + 1), command.every):
            k = tick // command.every
            for m in range(plan_first[k], plan_first[k + 1]):
                out_id[ls[L_OUT]], out_data[ls[L_OUT]] = plan_id[m], plan_data[m]
                ls[L_OUT] += 1
                queue(CMD, int(plan_id[m]), plan_data[m].tobytes())
            ls[L_PLAYED] = tick
        plant.start(lambda frame_id, data: queue(PLANT, frame_id, data))
        plant.to_compiled(ns, nf)
        fn, node = frame_fn_address(), self.ecu.address
        try:
            while True:
                why = run_frames(
                    ls, q_id, q_origin, q_data, out_id, out_data, plan_first, plan_id, plan_data,
                    ids, fn, node, ecu_out, state, tables, ns, nf, plant._layout, plant._buf,
                    self.truth,
                )  # fmt: skip
                self._hand_over(ls, out_id, out_data, whole_ticks=True)
                if progress is not None:
                    progress(int(ls[L_ANSWERED]))
                if why in (DONE, IDLE):
                    break
                if why == PLANT_FRAME:  # the plant node takes it in Python, at its tick
                    plant.from_compiled(ns, nf)
                    slot = int(ls[L_FAULT_SLOT])
                    plant.on_frame(int(q_id[slot]), q_data[slot].tobytes(), _no_send)
                    plant.to_compiled(ns, nf)
                elif why == PLANT_PYTHON:
                    plant.from_compiled(ns, nf)
                    plant.python_part()
                    plant.to_compiled(ns, nf)
        finally:
            self._hand_over(ls, out_id, out_data, whole_ticks=False)
            plant.from_compiled(ns, nf)
            played = int(ls[L_PLAYED])
            for tick in sorted(t for t in command.faults if t <= played):
                command.injected += command.injections_at(tick)
            command.finished = bool(ls[L_FINISHED])

    def _hand_over(
        self, ls: np.ndarray, out_id: np.ndarray, out_data: np.ndarray, *, whole_ticks: bool
    ) -> None:
        """The chunk's frames to the recorder: its whole ticks (all of them when not
        ``whole_ticks``: the run ends), in blocks; the frames up to the first EcuActuator, and
        those after the last, one by one as the command node records them. The rest of the
        chunk moves to its start."""
        end = int(ls[L_BOUNDARY]) if whole_ticks else int(ls[L_OUT])
        if whole_ticks and end == 0 and ls[L_OUT] >= ls[L_LIMIT]:
            self._one_by_one = True  # a chunk without an answer of the ECU: no whole ticks
        if self._one_by_one:
            end = int(ls[L_OUT])
            ls[L_BOUNDARY] = 0
        begin = 0
        if self._first_tick and ls[L_BOUNDARY] > 0:
            begin = int(np.flatnonzero(out_id[:end] == ACTUATOR)[0]) + 1
            self._record_one_by_one(out_id[:begin], out_data[:begin])
            self._first_tick = False
        whole = int(ls[L_BOUNDARY]) if not self._first_tick else 0
        if whole > begin:
            self.recorder.record_ticks(out_id[begin:whole], out_data[begin:whole])
            begin = whole
        if end > begin:
            self._record_one_by_one(out_id[begin:end], out_data[begin:end])
        rest = int(ls[L_OUT]) - end
        out_id[:rest] = out_id[end : end + rest]
        out_data[:rest] = out_data[end : end + rest]
        ls[L_OUT] = rest
        ls[L_BOUNDARY] = 0

    def _record_one_by_one(self, frame_ids: np.ndarray, payload: np.ndarray) -> None:
        """As CommandNode.on_frame records: each frame, and ``commands_sent`` once the command
        node's frames sent on a PlantSensors frame are in."""
        record, commands_sent = self.recorder.record, self.recorder.commands_sent
        sent_on_sensors = False
        own = self._own_ids
        for frame_id, data in zip(frame_ids.tolist(), payload, strict=True):
            if sent_on_sensors and frame_id not in own:
                commands_sent()
                sent_on_sensors = False
            record(frame_id, data.tobytes())
            if frame_id == SENSORS:
                sent_on_sensors = True
        if sent_on_sensors:
            commands_sent()


def _no_send(frame_id: int, data: bytes | bytearray) -> None:
    raise RuntimeError(f"the plant node sent frame 0x{frame_id:X} on a frame it takes in Python")
