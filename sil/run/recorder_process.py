"""The recorder in a process of its own, for in-process and lockstep runs.

In ``--mode inproc`` the plant, the ECU and the command node take turns on one core, and the
recorder's work (sorting frames into ticks, E2E checks, formatting can.log and trace.csv) is a
quarter to a third of the run; in lockstep the plant and the ECU processes take turns, and the
recorder's work in the run's process competed with them for the two cores. :class:`RecorderProcess`
stands where the :class:`~sil.record.recorder.Recorder` stands for the command node: it takes the
frames, and the command node's ``commands_sent``, in order and sends them in batches to a child
process, which hands them in the same order to a Recorder there (whole ticks given at once, by
``record_ticks``, go as one message, after the frames before them). The files are therefore the
ones the Recorder writes in the run's process, byte for byte. The child is on no node's critical
path, so once its Recorder is made it runs at the lowest priority (niceness 19): a node that wakes
up takes the core from it at once, and it still gets a share of a busy machine, so it never
starves. (Its start-up, imports and all, runs at the run's priority: at the lowest, on a machine
loaded by other work, it would take minutes.) On a loaded machine it may fall behind the run; its
parent waits for it as long as it works (:meth:`RecorderProcess.close`).

While the run goes, the command node reads back the newest sensor tick (taken from the frames
here, as the Recorder takes it) and the ticks answered: one per EcuActuator, since no frame is
lost between the nodes (in process there is no bus; on the loopback bus a sender's frames come in
its order; runs with bus faults and real-time runs keep the Recorder in the run's process). The
figures of the run (:meth:`totals`) are the child's, at close.

The child is started before the run is set up, so that it imports while the run does; it reads
its settings (:meth:`RecorderProcess.open`) and then the batches from its stdin (a feeder thread
writes them, so the run goes on while the child starts) and sends its figures back on its
stdout. It ignores Ctrl-C (the run stops and closes it, so that it writes everything); should the
run die, it writes what it was given and ends. If it fails, the next batch raises
:class:`RecorderFailed`; what it was given until then is on disk.
"""

from __future__ import annotations

import os
import pickle
import queue
import select
import signal
import subprocess
import sys
import threading
import time
from array import array
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO, NoReturn, TypeVar

import numpy as np

from protocol.codec import Codec
from sil.record.recorder import Recorder
from sil.record.ticks import InOrderTicks, tick_block
from sil.run.parent_death import die_with_parent

BATCH_FRAMES = 4096  # frames per message to the child (about 55 kB)
_COMMANDS_SENT = -1  # in the ID stream: the command node's commands_sent()
READY = b"R"  # the child to the parent: its Recorder is made (then, at the end, its figures)
ERROR = "error"  # ... or, in place of its figures, why it failed (a file it could not write)
_TICKS = "ticks"  # tags a block of whole ticks: (_TICKS, int32 IDs, (frames, 8) uint8 payload)
T = TypeVar("T")
CLOSE_TIMEOUT_S = 60.0  # the child's start, or its last chunk: at most this long asleep
NICE = 19  # the child's niceness: it is on no node's critical path, so a node that wakes up
# never waits for it (SCHED_IDLE did no better, and an unprivileged process could not leave it to
# write its last chunks on a busy machine)


class RecorderFailed(RuntimeError):
    """The recorder process is gone (what it had been given is on disk); ``write_error``: it
    could not write a file (the message names it)."""

    def __init__(self, message: str, *, write_error: bool = False) -> None:
        super().__init__(message)
        self.write_error = write_error


class RecorderProcess(InOrderTicks):
    """Made before the run is set up (the child then imports while it is), told where to write
    by :meth:`open`; :meth:`discard` if the run never starts."""

    def __init__(self) -> None:
        self._child = subprocess.Popen(
            [sys.executable, "-m", "sil.run.recorder_process"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            preexec_fn=_child_setup if os.name == "posix" else None,  # (before exec)
        )
        # a feeder thread writes the batches, so that the run goes on while the child starts
        self._outbox: queue.SimpleQueue = queue.SimpleQueue()
        self._feeder = threading.Thread(target=self._feed, name="sil-recorder-feed", daemon=True)
        self._broken = False
        self._ready = False  # the child's READY has been read
        self._feeder.start()
        super().__init__()
        self.frames = 0
        self._ids = array("i")
        self._lengths = bytearray()
        self._data = bytearray()
        self._totals: dict | None = None

    def open(
        self,
        out_dir: Path,
        period_s: float,
        *,
        commands: np.ndarray | None = None,
        channel: str = "vcan0",
        wait: bool = True,
    ) -> RecorderProcess:
        """The child's Recorder settings (see :class:`~sil.record.recorder.Recorder`): from now on
        it takes frames. Returns once the child has made its Recorder (its files open), as the
        in-process Recorder is made before a run begins, unless not ``wait``: then the child's
        start-up overlaps what comes next. A child that could not make it fails the first frame
        sent, or close, with :class:`RecorderFailed`."""
        self._outbox.put((out_dir, period_s, commands, channel))
        if wait:
            self._wait_ready()
        return self

    def _wait_ready(self) -> None:
        stdout = self._child.stdout
        assert stdout is not None
        ready = self._while_working(lambda s: bool(select.select([stdout], [], [], s)[0]))
        if not ready or stdout.read(1) != READY:  # (the child failed: its exit code tells)
            self._broken = True
        self._ready = True

    def _while_working(self, wait: Callable[[float], bool]) -> bool:
        """``wait(seconds)`` until it returns True, for as long as the child is working (it,
        or a child of it, uses CPU time or is runnable: on a loaded machine it is slow, not
        stuck); False once it has been asleep, using no CPU time, for CLOSE_TIMEOUT_S."""
        from sil.run.watchdog import sample

        pid = self._child.pid
        cpu, idle_since = None, time.monotonic()
        while not wait(1.0):
            got = sample([pid]).get(pid)
            now = time.monotonic()
            if got is not None and (got.working or got.cpu_ticks != cpu):
                cpu, idle_since = got.cpu_ticks, now
            elif now - idle_since > CLOSE_TIMEOUT_S or self._child.poll() is not None:
                return False
        return True

    def discard(self) -> None:
        """The run ended before it began: the child goes without writing anything."""
        self._outbox.put(None)
        self._feeder.join(CLOSE_TIMEOUT_S)
        if self._child.stdout is not None:
            self._child.stdout.close()
        self._reap()

    def _feed(self) -> None:
        pipe = self._child.stdin
        assert pipe is not None
        try:
            while True:
                message = self._outbox.get()
                pickle.dump(message, pipe, protocol=pickle.HIGHEST_PROTOCOL)
                pipe.flush()
                if message is None:
                    break
        except OSError:  # (BrokenPipeError: the child is gone)
            self._broken = True
        finally:
            try:
                pipe.close()
            except OSError:  # (what was left in the buffer has nowhere to go)
                pass

    def record(self, frame_id: int, data: bytes | bytearray, wall_s: float | None = None) -> None:
        # in this order, so that a Ctrl-C between two of these lines leaves no half frame: the
        # child takes a frame by its ID, and data without one is never read
        self._data += data
        self._lengths.append(len(data))
        self._ids.append(frame_id)
        self.frames += 1
        self.track(frame_id, data)
        if len(self._ids) >= BATCH_FRAMES:
            self._send_batch()

    def commands_sent(self) -> None:
        self._ids.append(_COMMANDS_SENT)

    def record_ticks(self, frame_ids: np.ndarray, payload: np.ndarray) -> None:
        """Whole ticks at once (see :meth:`~sil.record.recorder.Recorder.record_ticks`), after the
        frames recorded one by one; checked here (ValueError, nothing sent), sent as one
        message."""
        ids, _ = tick_block(frame_ids, payload, self.tick, self._sensor_wrap.last)
        if not len(ids):
            return
        if self._ids:
            self._send_batch()  # the frames before the block first
        data = np.ascontiguousarray(payload, np.uint8)
        self._send((_TICKS, ids.astype(np.int32).tobytes(), data.tobytes()))
        self.frames += len(ids)
        self.track_many(ids, data)

    def _send_batch(self) -> None:
        self._send((self._ids.tobytes(), bytes(self._lengths), bytes(self._data)))
        self._ids, self._lengths, self._data = array("i"), bytearray(), bytearray()

    def _send(self, message: tuple) -> None:
        if self._broken or self._child.poll() is not None:
            raise self._failure()
        self._outbox.put(message)

    def _failure(self) -> RecorderFailed:
        try:
            code = self._child.wait(5.0)
        except subprocess.TimeoutExpired:
            return RecorderFailed("the recorder process stopped taking frames")
        said = self._child_error()
        if said is not None:
            return RecorderFailed(said, write_error=True)
        return RecorderFailed(f"the recorder process exited with code {code}")

    def _child_error(self) -> str | None:
        """What the child said failed it (a file it could not write), once it has exited."""
        stdout = self._child.stdout
        if stdout is None or stdout.closed or self._child.poll() is None:
            return None
        try:
            if not self._ready:
                if stdout.read(1) != READY:
                    return None
                self._ready = True
            said = pickle.load(stdout)
        except (OSError, EOFError, ValueError, pickle.UnpicklingError):
            return None
        return str(said[ERROR]) if isinstance(said, dict) and ERROR in said else None

    def close(self) -> None:
        """Send what is left, let the child write it and close its files; take its figures."""
        if self._totals is not None:
            return
        self._totals = {  # what is known here, should the child not answer
            "tick": self.tick,
            "frames": self.frames,
            "bits": 0,
            "missed_ticks": 0,
            "e2e": {},
            "unknown_ids": {},
            "wrong_length": {},
        }
        interrupted: list[KeyboardInterrupt] = []
        self._catch_up()
        try:
            if self._ids:
                self._send_batch()
            self._outbox.put(None)
            _patiently(lambda: self._while_working(self._feeder_done), interrupted)
            if self._feeder.is_alive():  # the child took nothing for a minute, asleep
                self._child.kill()
                raise RecorderFailed("the recorder process stopped taking frames")
            self._totals = _patiently(self._read_totals, interrupted)
        finally:
            if self._child.stdout is not None:
                self._child.stdout.close()
            # its files are closed; its interpreter's teardown (0.1-0.3 s) is not waited for
            threading.Thread(target=self._reap, name="sil-recorder-reap", daemon=True).start()
        if interrupted:  # the Ctrl-C that came while the child finished its files, now
            raise interrupted[0]

    def _catch_up(self) -> None:
        """The run is over (its nodes stopped): the child, which may be behind on a loaded
        machine, goes back to the run's priority to write what is left, where this process may
        raise it again (root, or a nice limit that allows it); else it stays where it was."""
        try:
            os.setpriority(os.PRIO_PROCESS, self._child.pid, os.getpriority(os.PRIO_PROCESS, 0))
        except OSError:
            pass

    def _feeder_done(self, seconds: float) -> bool:
        self._feeder.join(seconds)
        return not self._feeder.is_alive()

    def _read_totals(self) -> dict:
        """The child's figures, sent once its files are closed."""
        stdout = self._child.stdout
        assert stdout is not None
        try:
            if not self._ready:
                if stdout.read(1) != READY:
                    raise EOFError
                self._ready = True
            totals = pickle.load(stdout)
        except (EOFError, pickle.UnpicklingError):
            raise self._failure() from None
        if ERROR in totals:  # the child could not write its files
            raise RecorderFailed(str(totals[ERROR]), write_error=True)
        return totals

    def _reap(self) -> None:
        try:
            self._child.wait(CLOSE_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self._child.kill()
            self._child.wait()

    def totals(self) -> dict:
        """The child Recorder's :meth:`~sil.record.recorder.Recorder.totals` (after close)."""
        if self._totals is None:
            raise RuntimeError("RecorderProcess.totals() before close()")
        return self._totals


def _patiently(wait: Callable[[], T], interrupted: list[KeyboardInterrupt]) -> T:
    """wait(), and once more if a Ctrl-C cuts it short: the child is finishing the run's files
    and stops on its own (the interrupt is kept in ``interrupted`` for the caller to raise); a
    second Ctrl-C is not held off."""
    try:
        return wait()
    except KeyboardInterrupt as exc:
        if interrupted:
            raise
        interrupted.append(exc)
        return wait()


def _child_setup() -> None:
    """In the child before exec: it dies with the run."""
    die_with_parent()


def _yield_to_the_nodes() -> None:
    """Once its Recorder is made (its imports and set-up at the run's priority, which on a
    loaded machine would crawl at the lowest), the child yields the cores to the nodes."""
    try:
        os.nice(NICE)
    except OSError:  # (not allowed here: it runs as it is)
        pass


def _exit(signum: int, _frame: object) -> None:
    raise SystemExit(128 + signum)


def serve(inbox: BinaryIO, outbox: BinaryIO) -> None:
    """The child: the Recorder's settings, then batches until None; its totals back at the end."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent ends the run and closes us
    signal.signal(signal.SIGTERM, _exit)  # the parent died: write what came, then go
    settings = _next(inbox)
    if settings is None:  # discarded: the run never began
        return
    out_dir, period_s, commands, channel = settings
    try:
        recorder = Recorder(out_dir, Codec(), period_s, commands=commands, channel=channel)
    except OSError as exc:
        _failed(outbox, exc, ready=False)
    outbox.write(READY)
    outbox.flush()
    _yield_to_the_nodes()
    error = None
    try:
        _take(inbox, recorder)
    except OSError as exc:  # a full disk, a file it may not write: the run is told why
        error = exc
    finally:
        try:
            recorder.close()
        except OSError as exc:
            error = error or exc
    if error is not None:
        _failed(outbox, error, ready=True)
    pickle.dump(recorder.totals(), outbox)
    outbox.flush()


def _take(inbox: BinaryIO, recorder: Recorder) -> None:
    """The batches, into the recorder, until the parent says there are no more."""
    while (batch := _next(inbox)) is not None:
        if isinstance(batch[0], str):  # (_TICKS, IDs, payload): whole ticks
            _, ids, data = batch
            frame_ids = np.frombuffer(ids, np.int32)
            recorder.record_ticks(frame_ids, np.frombuffer(data, np.uint8).reshape(-1, 8))
            continue
        ids, lengths, data = batch
        record, commands_sent = recorder.record, recorder.commands_sent
        at = 0
        length = iter(lengths)
        for frame_id in array("i", ids):
            if frame_id == _COMMANDS_SENT:
                commands_sent()
                continue
            end = at + next(length)
            record(frame_id, data[at:end])
            at = end


def _failed(outbox: BinaryIO, error: OSError, *, ready: bool) -> NoReturn:
    """Tell the parent why the recorder failed (in place of its figures), and end."""
    try:
        if not ready:
            outbox.write(READY)
        pickle.dump({ERROR: str(error)}, outbox)
        outbox.flush()
    except OSError:  # the parent is gone
        pass
    raise SystemExit(3)


def _next(inbox: BinaryIO) -> tuple | None:
    try:
        return pickle.load(inbox)
    except EOFError:  # the parent is gone: what came is written
        return None


if __name__ == "__main__":
    serve(sys.stdin.buffer, sys.stdout.buffer)
