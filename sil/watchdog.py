"""Liveness of a run on a bus: every node owes frames, and SIGTERM ends a run as Ctrl-C does.

A node process that stops answering without dying (SIGSTOP, a deadlock) would otherwise leave
``sil run`` waiting: its peer runs on its own clock after the guard time and the run never ends.
The command node hears every frame on the bus, so the run keeps, per frame ID, when it last heard
it (wall clock) and, every check, which node has sent nothing of what the DBC says it sends for
:data:`SILENCE_S`.
"""

from __future__ import annotations

SILENCE_S = 4.0  # checked every 0.2 s: a stuck node is found within 4.2 s of its last frame
NODES = {"Plant": "plant", "ECU": "ECU"}  # DBC sender -> the name the abort reason gives


class Terminated(KeyboardInterrupt):
    """SIGTERM: the run ends as on Ctrl-C, with its own reason."""


def interrupt_reason(exc: KeyboardInterrupt) -> str:
    return "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted (Ctrl-C)"


class Watchdog:
    """Which node sends which frame IDs (``messages``: the codec's, with ``frame_id`` and
    ``senders``), and when each node was last heard."""

    def __init__(self, messages, now: float, silence_s: float = SILENCE_S) -> None:
        self.silence_s = silence_s
        self.node_of = {m.frame_id: NODES[s] for m in messages for s in m.senders if s in NODES}
        self.heard_at = dict.fromkeys(NODES.values(), now)

    def silent(self, seen: dict[int, float], now: float) -> str | None:
        """The reason to abort if a node has been silent too long, else None. ``seen``: when
        each frame ID was last heard (other IDs are ignored)."""
        for frame_id, at in seen.items():
            node = self.node_of.get(frame_id)
            if node is not None and at > self.heard_at[node]:
                self.heard_at[node] = at
        for node, at in self.heard_at.items():
            if now - at > self.silence_s:
                return f"the {node} sent no frame for {now - at:.1f} s (stopped or stuck)"
        return None
