"""DAQ from the ECU's XCP slave into an MF4 with the A2L's names, units and conversions
(`sil xcp record`).

pyXCP is the master, on any bus of :mod:`protocol.bus`: it connects (retrying until the slave
answers), unlocks DAQ with the seed and key of :mod:`ecu.xcp.seed_key`, runs one DAQ list of
the measurements named on an event (0: the control tick) for a time or until told to stop, and
keeps every sample. The A2L, read with pya2ldb as the field's tools read it, gives each
measurement's address, type and COMPU_METHOD, and the XCP identifiers (``XCP_ON_CAN``); the MF4
(:func:`sil.record.mdf.write_measurements`) holds one channel group for the list: a channel per
measurement, named as in the A2L, with its raw values, its conversion (LINEAR, RAT_FUNC,
TAB_VERB, TAB_INTP, TAB_NOINTP) and its unit, so that a tool shows physical values. The time
channel is the ECU's DAQ timestamps (its clock: simulated time in lockstep) from the first
sample, as pyXCP hands them over (counted from the first, their wrap-around undone); the
header's start is the wall-clock time that first sample arrived.

    report = record(bus, Path("turbojet_ecu.a2l"), ["speed_rpm", "egt"], 5.0, Path("daq.mf4"))
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np

from sil.record import mdf
from sil.record.a2l import TYPES, XCP_INSTALL, A2l, A2lError, Measurement
from sil.record.xcp_master import connect, master


class RecordError(A2lError):
    """A recording refused or failed (``code`` 1: no answer, no sample)."""


def pick(a2l: A2l, names: list[str]) -> list[Measurement]:
    """The A2L's measurements by name, in order (RecordError naming those it has not)."""
    missing = [n for n in names if n not in a2l.measurements]
    if missing:
        known = ", ".join(sorted(a2l.measurements)[:12])
        raise RecordError(
            f"--measure: {', '.join(missing)}: no such MEASUREMENT in the A2L (it has "
            f"{len(a2l.measurements)}: {known}, ...)"
        )
    unsupported = [n for n in names if a2l.measurements[n].datatype not in TYPES]
    if unsupported:
        raise RecordError(f"--measure: {', '.join(unsupported)}: a data type DAQ cannot record")
    if len(set(names)) != len(names):
        raise RecordError("--measure: a measurement named twice")
    return [a2l.measurements[n] for n in names]


# -- the master ----------------------------------------------------------------------------


def _policy(measurements: list[Measurement], event: int, prescaler: int):  # noqa: ANN202
    """pyXCP's DAQ policy keeping every sample of one list in memory: ``rows`` of (arrival
    time in ns since the epoch, the slave's timestamp in ns, the values)."""
    from pyxcp.daq_stim import DaqList, DaqOnlinePolicy

    daq_list = DaqList(
        name="sil_xcp_record",
        event_num=event,
        stim=False,
        enable_timestamps=True,
        measurements=[(m.name, m.address, m.extension, TYPES[m.datatype][0]) for m in measurements],
        priority=0,
        prescaler=prescaler,
    )

    class Keep(DaqOnlinePolicy):
        def __init__(self) -> None:
            super().__init__([daq_list], logger=logging.getLogger("sil.record.xcp_record"))
            self.pid_off = False  # (pyXCP sets it only when it reads its own configuration)
            self.rows: list[tuple[int, int, list]] = []
            self.lock = threading.Lock()

        @property
        def names(self) -> list[str]:
            return [h[0] for h in daq_list.headers]

        def initialize(self) -> None:
            pass

        def finalize(self) -> None:
            pass

        def on_daq_list(self, daq: int, ts0: int, ts1: int, payload: list) -> None:
            with self.lock:
                self.rows.append((time.time_ns(), ts1, list(payload)))

    return Keep()


@dataclass
class Recording:
    """Samples of one DAQ list: time from the first (s, the ECU's clock), raw values."""

    measurements: list[Measurement]
    t: np.ndarray
    raw: dict[str, np.ndarray]
    start_us: int  # when the first sample arrived, µs since the epoch
    identification: str | None
    notes: list[str]


def _daq_info(x, attempts: int = 3) -> dict:  # noqa: ANN001 (pyXCP's Master)
    """The slave's DAQ processor and resolution info, asked again when an answer was lost (a
    loaded bus drops a frame now and then; pyXCP marks the info incomplete, it does not ask
    again). RuntimeError after ``attempts`` incomplete answers."""
    for _ in range(attempts):
        info = x.getDaqInfo(include_event_lists=False)
        valid = info.get("valid", {})
        if valid.get("processor", True) and valid.get("resolution", True):
            return info
    raise RuntimeError(f"no complete DAQ processor and resolution info in {attempts} attempts")


def record(
    bus: can.BusABC,
    a2l: A2l,
    measurements: list[Measurement],
    seconds: float,
    *,
    event: int = 0,
    prescaler: int = 1,
    connect_timeout_s: float = 10.0,
    stop: threading.Event | None = None,
    ids: tuple[int, int] | None = None,
) -> Recording:
    """Record ``measurements`` on ``event`` for ``seconds`` (or until ``stop`` is set) with
    pyXCP as the master on ``bus``. RecordError: pyXCP missing (2), no answer, a refusal, no
    sample (1). The end of a session the ECU no longer answers (it stopped) costs nothing of
    what was recorded: it is noted."""
    try:
        from pyxcp.types import XcpResponseError, XcpTimeoutError
    except ImportError as exc:
        raise RecordError(f"recording needs pyXCP ({exc}); install: {XCP_INSTALL}") from None
    ids = ids or a2l.ids
    if ids is None:
        from protocol.dbc import xcp_frame_ids

        ids = xcp_frame_ids()
    policy = _policy(measurements, event, prescaler)
    notes: list[str] = []
    where = f"the XCP slave (0x{ids[0]:X}/0x{ids[1]:X})"

    def session(x) -> tuple[RecordError | None, str | None]:  # noqa: ANN001 (pyXCP's Master)
        """The session; what went wrong is returned, not raised: pyXCP's master logs (with its
        traceback) an exception that leaves it."""
        try:
            connect(x, connect_timeout_s)
        except XcpTimeoutError:
            return RecordError(f"no answer from {where} within {connect_timeout_s:g} s", 1), None
        try:
            x.getCommModeInfo()
            identification = x.identifier(0)
            x.cond_unlock("DAQ")
            policy.setup(daq_info_override=_daq_info(x))
            policy.start()
        except (XcpResponseError, XcpTimeoutError, RuntimeError) as exc:
            return RecordError(f"{where} refused the DAQ list: {mdf.one_line(exc)}", 1), None
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not (stop is not None and stop.is_set()):
            time.sleep(min(0.05, max(0.0, deadline - time.monotonic())))
        try:
            policy.stop()
            x.disconnect()
        except (XcpResponseError, XcpTimeoutError, OSError, can.CanError) as exc:
            notes.append(f"the session did not end cleanly ({mdf.one_line(exc)}): the ECU "
                         "stopped answering; what it sent before is kept")  # fmt: skip
        return None, identification

    pyxcp_log = logging.getLogger("pyxcp")
    disabled, pyxcp_log.disabled = pyxcp_log.disabled, True  # (its own console handler)
    try:
        with master(bus, ids, policy) as x:
            failure, identification = session(x)
    finally:
        pyxcp_log.disabled = disabled
    if failure is not None:
        raise failure
    with policy.lock:
        rows = list(policy.rows)
    if not rows:
        raise RecordError(f"no DAQ sample from {where} on event {event}", 1)
    stamps = np.array([r[1] for r in rows], np.float64)  # ns, from the first, unwrapped
    t = (stamps - stamps[0]) / 1e9
    names = policy.names
    raw: dict[str, np.ndarray] = {}
    for m in measurements:
        column = np.array([r[2][names.index(m.name)] for r in rows])
        values = column.astype(TYPES[m.datatype][1])
        if m.mask is not None:
            shift = (m.mask & -m.mask).bit_length() - 1
            values = (values & values.dtype.type(m.mask)) >> values.dtype.type(shift)
        raw[m.name] = values
    if identification and a2l.epk and identification.strip() != a2l.epk.strip():
        notes.append(f"the ECU says '{identification}', the A2L's EPK is '{a2l.epk}': "
                     "an A2L of another build")  # fmt: skip
    return Recording(
        measurements=measurements,
        t=t,
        raw=raw,
        start_us=rows[0][0] // 1000,
        identification=identification,
        notes=notes,
    )


def write(path: Path, recording: Recording, a2l: A2l, a2l_path: Path, event: int) -> None:
    """The recording as an MF4 (atomically: WriteError names the file)."""
    event_name = a2l.events.get(event, f"event {event}")
    channels = [
        mdf.Channel(
            name=m.name, raw=recording.raw[m.name], conversion=m.conversion, unit=m.unit,
            comment=m.comment,
        )
        for m in recording.measurements
    ]  # fmt: skip
    comment = (
        f"XCP DAQ of {a2l.name or 'the ECU'} (A2L {a2l_path.name}; ECU "
        f"'{recording.identification or '?'}') on event {event} ({event_name}), recorded by "
        "turbojet-sil with pyXCP; time: the ECU's DAQ timestamps from the first sample, which "
        "arrived at the start" + "".join(f"; note: {n}" for n in recording.notes)
    )
    mdf.write_measurements(
        path,
        recording.start_us,
        recording.t,
        channels,
        group=event_name,
        source=a2l.name or "ECU",
        source_path="XCP on CAN",
        comment=comment,
    )


def summary(recording: Recording, path: Path, event: int) -> dict:
    n = len(recording.t)
    span = float(recording.t[-1]) if n else 0.0
    return {
        "out": str(path),
        "samples": n,
        "measurements": [m.name for m in recording.measurements],
        "event": event,
        "seconds": span,
        "rate_hz": (n - 1) / span if n > 1 and span > 0 else math.nan,
        "start": mdf.format_start(recording.start_us),
        "ecu": recording.identification,
        "notes": recording.notes,
    }
