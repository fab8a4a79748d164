"""Child processes of a run die with it: Linux sends them SIGTERM when the parent ends
(``PR_SET_PDEATHSIG``), however it ends, so a killed run leaves no process behind. A parent
killed before its child asked for that signal sends none; so the child is also told its parent's
pid (``PARENT_ENV``) and a node stops as on SIGTERM once its parent is another (``NodeStop``).
A node whose peer the run found dead is told so (``PeerLost``)."""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
from collections.abc import Callable

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
PARENT_ENV = "SIL_PARENT_PID"


def die_with_parent() -> None:
    """Ask for SIGTERM when the parent process ends (Linux; elsewhere nothing)."""
    if sys.platform == "linux":
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def child_env() -> dict[str, str]:
    """The environment entry that tells a spawned node who its parent is."""
    return {PARENT_ENV: str(os.getpid())}


class NodeStop:
    """A node's stop request: SIGTERM (handled when this is the main thread) or, for a node a
    run spawned, its parent gone (the node is then another's child)."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self._parent = int(os.environ.get(PARENT_ENV, "0") or 0)
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, lambda *_: self._event.set())

    def set(self) -> None:
        self._event.set()

    def is_set(self) -> bool:
        if not self._event.is_set() and self._parent and os.getppid() != self._parent:
            self._event.set()
        return self._event.is_set()


PEER_LOST_SIGNAL = signal.SIGUSR1
PEER_LOST_GUARD_S = 0.02  # a node told its peer is gone waits no longer than this for a frame


class PeerLost:
    """The run's word that this node's peer is gone (``sil run`` sends SIGUSR1 once it has
    found the peer dead, stopped or stuck): in lockstep the node, which waited as long as the
    run let it, now runs on its own clock (its guard becomes :data:`PEER_LOST_GUARD_S`), so
    that its reaction to the loss is recorded; ``on_lost`` runs then (in the main thread)."""

    def __init__(self, on_lost: Callable[[], None] | None = None) -> None:
        self._lost = False
        self._on_lost = on_lost
        if threading.current_thread() is threading.main_thread():
            signal.signal(PEER_LOST_SIGNAL, self._handle)

    def _handle(self, *_: object) -> None:
        self._lost = True
        if self._on_lost is not None:
            self._on_lost()

    def is_set(self) -> bool:
        return self._lost

    def guard(self, guard_s: float) -> Callable[[], float]:
        """The node's lockstep guard: ``guard_s`` until the peer is lost."""
        return lambda: PEER_LOST_GUARD_S if self._lost else guard_s
