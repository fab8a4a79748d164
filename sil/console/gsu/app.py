"""The ground-support page put together: two bus connections (one reads every frame for the
live values and recordings, one is the XCP master's), the A2L, the poller and the web server.

    app = App.open("udp:239.255.7.7", a2l, (0x700, 0x701), Path("."))
    server = app.serve("127.0.0.1", 8470)   # server.serve_forever(); then app.close()
"""

from __future__ import annotations

import contextlib
import secrets
import threading
import time
from pathlib import Path

import can

from protocol.bus import open_bus
from sil.console.gsu.live import Live
from sil.console.gsu.server import Gsu, serve
from sil.console.gsu.xcp_link import Refused, XcpLink
from sil.record.a2l import A2l

READ_TIMEOUT_S = 0.1


class App:
    def __init__(self, live_bus: can.BusABC, xcp_bus: can.BusABC, gsu: Gsu) -> None:
        self.live_bus = live_bus
        self.xcp_bus = xcp_bus
        self.gsu = gsu
        self._threads: list[threading.Thread] = []
        self._running = threading.Event()
        self._running.set()

    @classmethod
    def open(
        cls, spec: str, a2l: A2l, ids: tuple[int, int], out_dir: Path, token: str | None = None
    ) -> App:
        live_bus = open_bus(spec)
        try:
            xcp_bus = open_bus(spec)
        except Exception:
            live_bus.shutdown()
            raise
        live = Live()
        link = XcpLink(xcp_bus, a2l, ids, live.running_for)
        gsu = Gsu(live, link, out_dir, token or secrets.token_urlsafe(16))
        return cls(live_bus, xcp_bus, gsu)

    def start(self) -> None:
        """The bus reader and the XCP poller, as daemon threads."""
        for target, name in ((self._read, "gsu-bus"), (self.gsu.poll_forever, "gsu-poll")):
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)

    def _read(self) -> None:
        while self._running.is_set():
            try:
                msg = self.live_bus.recv(READ_TIMEOUT_S)
            except (can.CanError, OSError):
                time.sleep(READ_TIMEOUT_S)
                continue
            if msg is not None:
                self.gsu.live.feed(msg, time.time())

    def serve(self, host: str, port: int):  # noqa: ANN201 (ThreadingHTTPServer)
        self.start()
        return serve(self.gsu, host, port)

    def close(self) -> str | None:
        """Stop; a recording under way is written first (what became of it is returned)."""
        self.gsu.stop()
        said = None
        if self.gsu.live.recorder is not None:
            try:
                done = self.gsu.record_stop()
                said = f"recording written: {done['path']} ({done['frames']} frames)"
            except Refused as exc:
                said = f"recording not written: {exc}"
        self._running.clear()
        for thread in self._threads:
            thread.join(timeout=2.0)
        self.gsu.link.close()
        for bus in (self.live_bus, self.xcp_bus):
            with contextlib.suppress(Exception):
                bus.shutdown()
        return said
