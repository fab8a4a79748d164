"""An orderly stop keeps the logbook: an ECU stopped (SIGTERM, Ctrl-C) while its engine cools
down, before it is at rest again, saves what it counted, and the next ECU on the same flash
image reads the run; a stop with nothing new counted writes nothing."""

from __future__ import annotations

import signal
import time

import can
import pytest

from ecu import logbook as L
from ecu import modes as M
from ecu.firmware import E2E_NONEWDATA, E2E_OK, Ecu, EcuInputs
from ecu.params import EcuParams
from ecu.service import logbook_save
from ecu.service.message import Service
from ecu.service.param_table import stored_logbook
from ecu.service.port import boot
from ecu.service.storage import load
from ecu.service.transport import open_transport
from protocol.bus import open_bus
from protocol.codec import Codec
from sil.console.client import ServiceClient
from tests.service.conftest import start_ecu

SPEED_RPM, EGT_DK, DEMAND_CPCT = 100_890, 10_480, 8_968  # a running engine, hot
RATE_HZ = EcuParams().rate_hz


def _hot_engine() -> EcuInputs:
    """Inputs of a running engine, armed: the ECU takes it over in RUN at once; the EGT stays
    hot, so that a stop cools it down for as long as the test runs."""
    i = EcuInputs()
    i.sensor_status = i.analog_status = E2E_OK
    i.speed_rpm, i.egt_dk, i.supply_mv, i.pump_ma = SPEED_RPM, EGT_DK, 22_200, 1_500
    i.demand_cpct, i.arm = DEMAND_CPCT, 1
    return i


def _expected(run_ticks: int) -> dict[str, int]:
    """The logbook of one run of ``run_ticks`` ticks in RUN on the hot engine, stopped by its
    operator (the arm released)."""
    words = {name: 0 for name in L.word_names()}
    words.update(
        log_runs=1, log_run_time_s=run_ticks // RATE_HZ, log_run_frac_ticks=run_ticks % RATE_HZ,
        log_last_max_egt_dk=EGT_DK, log_last_max_speed_cpct=DEMAND_CPCT,
        log_last_shutdown=L.SD_OPERATOR_STOP,
    )  # fmt: skip
    return words


def test_a_stop_in_the_cool_down_saves_the_run_and_a_stop_at_rest_saves_nothing(tmp_path):
    path = tmp_path / "flash.bin"
    booted = boot(EcuParams(), path)
    ecu = Ecu(booted.table.firmware)
    saver = logbook_save.boot_saver(ecu, booted)
    assert saver.at_stop() is None and load(path) is None  # nothing counted: nothing written
    i = _hot_engine()
    run_ticks = 0
    for k in range(240):
        i.demand_status = E2E_OK if k % 5 == 0 else E2E_NONEWDATA
        i.arm = int(k < 130)
        ecu.tick(i)
        saver.after_tick()
        run_ticks += ecu.out.mode == M.RUN
    assert ecu.out.mode == M.SHUTDOWN and load(path) is None  # cooling: not at rest yet
    slot = saver.at_stop()
    assert slot is not None and stored_logbook(load(path).payload) == _expected(run_ticks)
    assert saver.at_stop() is None and load(path).sequence == slot.sequence  # held already
    booted.flash.close()


def _drive_to_cool_down(spec: str, run_ticks: int, ticks: int) -> list[int]:
    """Lockstep ticks of the hot engine on ``spec``: armed for ``run_ticks``, then released;
    the ECU's mode at each tick, from its EcuActuator frames."""
    codec = Codec()
    sensors, analog, demand = codec["PlantSensors"], codec["PlantAnalog"], codec["Demand"]
    actuator = codec["EcuActuator"]
    bus = open_bus(spec)
    modes = []
    raw = [0] * len(actuator.signal_names)
    try:
        for k in range(ticks):
            if k % 5 == 0:
                _send(bus, demand, [int(k < run_ticks), 0, DEMAND_CPCT, 0, k])
                _send(bus, analog, [k, 22_200, 1_500])
            _send(bus, sensors, [k, SPEED_RPM, EGT_DK])
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                reply = bus.recv(0.5)
                if reply is not None and reply.arbitration_id == actuator.frame_id:
                    actuator.unpack_raw(reply.data, raw)
                    if raw[2] == k:
                        modes.append(raw[1])
                        break
            assert len(modes) == k + 1, f"no EcuActuator for tick {k}"
    finally:
        bus.shutdown()
    return modes


def _send(bus, message, values: list[int]) -> None:  # noqa: ANN001
    message.pack_raw(values)
    bus.send(can.Message(arbitration_id=message.frame_id, data=message.data, is_extended_id=False))


@pytest.mark.slow
@pytest.mark.parametrize(
    ("impl", "stop"),
    [("python", signal.SIGTERM), ("c", signal.SIGINT)],
    ids=["python-SIGTERM", "c-SIGINT"],
)
def test_an_ecu_stopped_in_the_cool_down_keeps_the_run(impl, stop, tmp_path, sil_process,
                                                       udp_spec):  # fmt: skip
    """`sil ecu --impl IMPL --flash FILE` in lockstep flies a run and its stop; stopped by a
    signal while the engine cools down, it saves the run; a new ECU on the file reads it over
    its service port (LOGBOOK_READ)."""
    flash, ready, spec = tmp_path / "flash.bin", tmp_path / "ready", udp_spec()
    ecu = sil_process(
        "ecu", "--impl", impl, "--bus", spec, "--flash", str(flash), "--guard", "60",
        "--ready-file", str(ready), "--json",
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while not ready.exists() and ecu.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert ready.exists(), "sil ecu did not start"
        modes = _drive_to_cool_down(spec, run_ticks=150, ticks=200)
        assert modes[-1] == M.SHUTDOWN and load(flash) is None  # cooling, nothing saved yet
        ecu.send_signal(stop)
        _, err = ecu.communicate(timeout=30)
    finally:
        if ecu.poll() is None:
            ecu.kill()
            ecu.communicate()
    assert ecu.returncode == 0, err
    assert f"logbook: saved at stop into {flash}" in err

    reader, port = start_ecu(flash, f"stop-{impl}")
    try:
        client = ServiceClient(open_transport(port), timeout_s=2.0)
        words = dict(zip(L.word_names(), client.request(Service.LOGBOOK_READ), strict=True))
        client.transport.close()
    finally:
        reader.terminate()
        reader.communicate(timeout=30)
    assert words == _expected(modes.count(M.RUN))
