"""Who belongs to a run, agreed before tick 0 through the node processes' handshake files.

On a bus that names each frame's sender (the loopback bus: every datagram carries its bus's
token), each node process says its token in its ready file (``ready TOKEN``). Once every node is
ready, the run names its senders, the command node's and the nodes', in the start file, which it
writes at once (a node waiting for it never reads half of it); each node reads them there
before its first tick, and from then on the nodes and the command node (and so the recorder)
hear only those senders: a second ECU or a replay that joins the bus during the set-up is
dropped and counted as another sender's whatever it carries (:meth:`protocol.run_bus.RunBus.admit`).

Where frames carry no sender (SocketCAN, an adapter) the ready file says only ``ready`` and the
start file names no one: the nodes hear every sender, and the run's sequence rules are all that
tell another sender's frames apart (:mod:`protocol.run_sequence`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

from protocol.run_bus import RunBus
from sil.record.results import write_atomically

START_POLL_S = 0.002  # how often a node looks for the start file


def say_ready(path: Path, bus: RunBus) -> None:
    """The node's ready file: ``ready``, with the token of its frames on ``bus`` if it has one."""
    token = bus.sender
    path.write_text(f"ready {token}\n" if token else "ready\n")


def sender_in(path: Path) -> str | None:
    """The token a ready file gives, or None (a bus without senders, or no such file)."""
    try:
        words = path.read_text().split()
    except OSError:
        return None
    return words[1] if len(words) == 2 and words[0] == "ready" else None


def give_start(path: Path, senders: Mapping[str, str]) -> None:
    """The start file, naming the run's ``senders`` (name -> token; none: every sender heard),
    written atomically, so that it appears whole."""
    write_atomically(path, "".join(f"{name} {token}\n" for name, token in senders.items()))


def senders_in(path: Path) -> dict[str, str]:
    """The run's senders the start file names (name -> token)."""
    pairs = (line.split() for line in path.read_text().splitlines())
    return {words[0]: words[1] for words in pairs if len(words) == 2}


def wait_to_start(path: Path, bus: RunBus, stopped: Callable[[], bool]) -> bool:
    """Wait for the start file (False: a stop came first), holding what the bus hears meanwhile
    (another run's traffic would overflow the node's queue); then hear only the run's senders
    it names, if it names any, what was held first."""
    while not path.exists():
        if stopped():
            return False
        bus.hold(START_POLL_S)
    senders = senders_in(path)
    if senders:
        bus.admit(senders.values())
    return True
