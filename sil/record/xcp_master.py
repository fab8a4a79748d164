"""pyXCP as the master on a bus of ours: configured in code, with the seed and key of
:mod:`ecu.xcp.seed_key`; refusals raised as pyXCP's ``XcpResponseError`` with their code."""

from __future__ import annotations

import logging
import time

import can


def master(bus: can.BusABC, ids: tuple[int, int], policy):  # noqa: ANN001, ANN202
    """pyXCP's master, configured in code, on ``bus``: XCP on CAN with ``ids``, the seed and
    key of :mod:`ecu.xcp.seed_key`, refusals raised (not pyXCP's own handling, which may end
    the process)."""
    from pyxcp.config import General, PyXCP, Transport
    from pyxcp.master import Master
    from traitlets.config import Config

    from ecu.xcp.seed_key import key_for

    c = Config()
    c.Transport.layer = "CAN"
    c.Transport.Can.interface = "virtual"  # (the bus is handed over, this is not opened)
    c.Transport.Can.can_id_master = ids[0]
    c.Transport.Can.can_id_slave = ids[1]
    c.General.seed_n_key_function = lambda resource, seed: key_for(bytes(seed))
    c.General.disable_error_handling = True
    app = PyXCP(config=c)
    app.log_level = logging.ERROR
    app._setup_logger()
    app.general = General(config=app.config, parent=app)
    app.transport = Transport(parent=app)
    return Master("CAN", config=app, policy=policy, transport_layer_interface=bus)


def connect(x, timeout_s: float) -> None:  # noqa: ANN001 (pyXCP's Master)
    """CONNECT until the slave answers (an ECU not yet up, a run still starting), every 0.2 s
    rather than after the whole command timeout, so that no more of a lockstep run goes by
    than needed. A slave that was busy answers the CONNECTs it held all at once: those answers
    are let arrive and dropped (XCP answers carry no request number, so a stale one would be
    taken as the answer to every later command in turn)."""
    from pyxcp.types import XcpTimeoutError

    transport = x.transport
    normal = transport.timeout
    transport.timeout = 200_000_000  # ns
    deadline = time.monotonic() + timeout_s
    sent = 0
    try:
        while True:
            try:
                sent += 1
                x.connect()
                break
            except XcpTimeoutError:
                if time.monotonic() > deadline:
                    raise
    finally:
        transport.timeout = normal
    if sent > 1:
        _drop_late_answers(transport)


def _drop_late_answers(transport, quiet_s: float = 0.3, limit_s: float = 5.0) -> int:  # noqa: ANN001
    """Drop the answers that arrive until none has for ``quiet_s`` (at most ``limit_s``); how
    many were dropped. (pyXCP's transport queues answers in ``resQueue``.)"""
    dropped, end = 0, time.monotonic() + limit_s
    while time.monotonic() < end:
        time.sleep(quiet_s)
        with transport.resQueue_condition:
            if not transport.resQueue:
                break
            dropped += len(transport.resQueue)
            transport.resQueue.clear()
    return dropped
