"""A service-port client: requests with sequence numbers, a timeout and retries; live samples.

The client speaks the protocol of :mod:`ecu.service.message` over any
:mod:`ecu.service.transport` (a serial device, the pty the ECU printed, a pyserial URL). Stream
samples that arrive while it waits for a response are kept in :attr:`ServiceClient.samples`.
``idle`` is called while waiting (by default a 1 ms sleep); an in-process test passes a function
that runs the ECU's ticks instead.
"""

from __future__ import annotations

import math
import random
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from ecu import logbook as L
from ecu.modes import NAMES as MODE_NAMES
from ecu.service import fault_log, live
from ecu.service.framing import FrameDecoder, encode_frame
from ecu.service.message import (
    Kind,
    Message,
    MessageError,
    Service,
    Status,
    pack,
    unlock_key,
    unpack,
)
from ecu.service.port import COUNTER_NAMES
from ecu.service.transport import Transport


class ServiceRequestError(RuntimeError):
    """The ECU refused a request; ``status`` says how, the message why."""

    def __init__(self, service: Service, status: int, message: str) -> None:
        name = Status(status).name if status in Status._value2member_map_ else str(status)
        super().__init__(f"{service.name}: {name}: {message}")
        self.status = status


class ServiceTimeout(TimeoutError):
    pass


RAW_MAX = (1 << 31) - 1  # a parameter's raw value is a signed 32-bit Q number
# the logbook's words (ecu.logbook.word_names) that are not plain counts: the name shown (the
# A2L's, without the unit's suffix), the unit, and what the word counts per unit
LOGBOOK_UNITS = {
    "log_run_time_s": ("log_run_time_s", "s", 1),
    "log_run_frac_ticks": ("log_run_frac_ticks", "ticks", 1),
    "log_last_max_egt_dk": ("log_last_max_egt", "K", 10),
    "log_last_max_speed_cpct": ("log_last_max_speed", "%N", 100),
}


def _sleep() -> None:
    time.sleep(0.001)


def finite_value(name: str, value: object) -> float:
    """``value`` (a number, or its text) as a finite float; else ValueError naming the
    parameter ``name``."""
    if isinstance(value, bool) or not isinstance(value, str | int | float):
        raise ValueError(f"set {name}: {value!r} is not a number")
    try:
        number = float(value)
    except OverflowError:  # an int beyond any float
        number = math.inf
    except ValueError:
        raise ValueError(f"set {name}: {value!r} is not a number") from None
    if not math.isfinite(number):
        raise ValueError(f"set {name}: {value} is not a finite number")
    return number


class ServiceClient:
    def __init__(
        self,
        transport: Transport,
        *,
        timeout_s: float = 1.0,
        retries: int = 2,
        idle: Callable[[], None] = _sleep,
        first_seq: int | None = None,
    ) -> None:
        self.transport = transport
        self.timeout_s = timeout_s
        self.retries = retries
        self.idle = idle
        self.decoder = FrameDecoder()
        self.samples: deque[list[int]] = deque(maxlen=10_000)
        self.stream_seq: int | None = None
        self.stream_gaps = 0  # stream samples lost (sequence numbers skipped)
        # a new client starts where its predecessor's numbers are unlikely to be (see REPEAT_S)
        self._seq = random.getrandbits(16) if first_seq is None else first_seq

    # -- transport ---------------------------------------------------------------------------
    def _write_all(self, data: bytes) -> None:
        deadline = time.monotonic() + self.timeout_s
        while data:
            n = self.transport.write(data)
            data = data[n:]
            if data:
                if time.monotonic() > deadline:
                    raise ServiceTimeout(f"{self.transport.name}: the line does not take data")
                self.idle()

    def receive(self) -> list[Message]:
        """Read what has arrived: stream samples are kept, other messages returned."""
        messages = []
        for payload in self.decoder.feed(self.transport.read(65536)):
            try:
                msg = unpack(payload)
            except MessageError:
                continue
            if msg.kind == Kind.STREAM and isinstance(msg.body, list):
                if self.stream_seq is not None:
                    self.stream_gaps += (msg.seq - self.stream_seq - 1) % 65536
                self.stream_seq = msg.seq
                self.samples.append(msg.body)
            else:
                messages.append(msg)
        return messages

    def request(self, service: Service, body: Any = None, timeout_s: float | None = None) -> Any:
        """Send a request and return the body of its response; raise on refusal or timeout."""
        self._seq = (self._seq + 1) & 0xFFFF
        seq = self._seq
        frame = encode_frame(pack(Message(Kind.REQUEST, seq, service, Status.OK, body)))
        wait = self.timeout_s if timeout_s is None else timeout_s
        for _ in range(self.retries + 1):
            self._write_all(frame)
            deadline = time.monotonic() + wait
            while time.monotonic() < deadline:
                self.idle()
                for msg in self.receive():
                    if msg.kind == Kind.RESPONSE and msg.seq == seq and msg.service == service:
                        if msg.status != Status.OK:
                            error = msg.body.get("error") if isinstance(msg.body, dict) else None
                            raise ServiceRequestError(service, msg.status, str(error))
                        return msg.body
        raise ServiceTimeout(
            f"{self.transport.name}: no answer to {service.name} within {wait:g} s "
            f"({self.retries + 1} tries)"
        )

    # -- services ----------------------------------------------------------------------------
    def identify(self) -> dict:
        return self.request(Service.IDENTIFY)

    def counters(self) -> dict:
        return dict(zip(COUNTER_NAMES, self.request(Service.COUNTERS), strict=True))

    def stream(self, rate_hz: float) -> dict:
        self.stream_seq = None
        return self.request(Service.STREAM, {"rate_hz": rate_hz})

    def latest(self) -> dict[str, int | float] | None:
        """The newest live sample in engineering units."""
        if not self.samples:
            return None
        return live.decode(self.samples[-1])

    def unlock(self) -> None:
        seed = self.request(Service.UNLOCK_SEED)["seed"]
        self.request(Service.UNLOCK_KEY, {"key": unlock_key(seed)})

    def params(self) -> list[dict]:
        """Every parameter with its Q format, unit, limits, run safety and value."""
        out = []
        for index in range(self.identify()["params"]):
            info = self.request(Service.PARAM_INFO, {"index": index})
            scale = 1.0 / (1 << info["frac"])
            bounds = {"min": info["lo"] * scale, "max": info["hi"] * scale}
            out.append({**info, **bounds, "value": info["raw"] * scale})
        return out

    def get(self, name: str) -> dict:
        r = self.request(Service.PARAM_READ, {"name": name})
        return {**r, "value": r["raw"] / (1 << r["frac"])}

    def raw_value(self, name: str, value: float) -> int:
        """The raw Q number that writes ``value`` (engineering units) to parameter ``name``,
        rounded to its Q format. A value that is not a finite number, or that the format cannot
        hold, is refused (ValueError naming the parameter); the ECU checks its own limits."""
        value = finite_value(name, value)
        frac = self.get(name)["frac"]
        scaled = value * (1 << frac)
        if not -RAW_MAX - 1 <= scaled <= RAW_MAX:
            top = (RAW_MAX + 1) / (1 << frac)
            raise ValueError(
                f"set {name}: {value:g} is more than its Q{31 - frac}.{frac} format holds "
                f"(-{top:g}..{top:g})"
            )
        return round(scaled)

    def set(self, name: str, value: float) -> dict:
        """Write a parameter in engineering units (:meth:`raw_value`); unlocks first."""
        raw = self.raw_value(name, value)
        self.unlock()
        r = self.request(Service.PARAM_WRITE, {"name": name, "raw": raw})
        return {**r, "value": r["raw"] / (1 << r["frac"])}

    def save(self) -> dict:
        self.unlock()
        return self.request(Service.PARAM_SAVE)

    def faults(self) -> list[dict]:
        """The fault log, oldest first, with names and snapshots in their units."""
        entries: list[list] = []
        while True:
            page = self.request(Service.FAULT_LOG_READ, {"start": len(entries)})
            entries += page["entries"]
            if not page["entries"] or len(entries) >= page["count"]:
                break
        rate = page["rate_hz"]
        return [
            {
                "time_s": tick / rate,
                "code": code,
                "name": fault_log.code_name(code),
                "snapshot": dict(zip(fault_log.SNAPSHOT_FIELDS, snap, strict=True)),
                "count": count,
                "last_s": last / rate,
            }
            for tick, code, snap, count, last in entries
        ]

    def logbook(self) -> list[dict]:
        """The engine's logbook: each word's name, value in its unit (the last shutdown by
        name) and unit, in the order of ecu.logbook.word_names."""
        rows = []
        for word, raw in zip(L.word_names(), self.request(Service.LOGBOOK_READ), strict=True):
            name, unit, per_unit = LOGBOOK_UNITS.get(word, (word, "", 1))
            value = raw / per_unit if per_unit != 1 else raw
            if word == "log_last_shutdown" and 0 <= raw < len(L.SHUTDOWN_NAMES):
                value = L.SHUTDOWN_NAMES[raw]
            rows.append({"name": name, "value": value, "unit": unit})
        return rows

    def clear_faults(self) -> int:
        self.unlock()
        return self.request(Service.FAULT_LOG_CLEAR)["cleared"]

    def arm(self) -> str:
        """Arm (the mode before it); the port becomes the demand source, at idle."""
        self.unlock()
        return MODE_NAMES[self.request(Service.ARM)["mode"]]

    def throttle(self, pct: float) -> dict:
        """The bench's speed demand, %N (0: idle): {"demand_pct", "source"}."""
        self.unlock()
        return self.request(Service.THROTTLE, {"pct": pct})

    def stop(self) -> str:
        return MODE_NAMES[self.request(Service.STOP)["mode"]]
