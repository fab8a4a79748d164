"""The engine's logbook in flash: saved with the parameter set (in its slot, with its sequence
and CRC) when the ECU is back at rest and with every parameter store, loaded at power-up; a
power cut in a save keeps the previous logbook; an image saved before the logbook still loads.
`sil ecu --flash FILE` keeps the counts over a restart, with the Python and the C ECU."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import can
import pytest

from ecu import logbook as L
from ecu.firmware import E2E_NONEWDATA, E2E_OK, Ecu, EcuInputs
from ecu.params import EcuParams
from ecu.service import logbook_save
from ecu.service.param_table import ParamTable, stored_logbook
from ecu.service.port import boot
from ecu.service.storage import FlashImage, load
from ecu.xcp import codes as C
from protocol.codec import Codec
from sil.cli import main
from tests.xcp.test_c_slave import Rigs


def _logbook(path: Path) -> dict | None:
    slot = load(path)
    return None if slot is None else stored_logbook(slot.payload)


def _start_and_release(ecu: Ecu, saver: logbook_save.LogbookSaver, ticks: int = 60) -> None:
    """An engine at rest: armed (a start begins), released in the spin-up (OFF at once: a
    STOPPED abort), then at rest while the saver writes."""
    i = EcuInputs()
    i.sensor_status = i.analog_status = E2E_OK
    i.speed_rpm, i.egt_dk, i.supply_mv, i.demand_cpct = 0, 2900, 22200, 3500
    for k in range(ticks):
        i.demand_status = E2E_OK if k % 5 == 0 else E2E_NONEWDATA
        i.arm = 1 if 5 <= k < 15 else 0
        ecu.tick(i)
        saver.after_tick()


def test_a_start_is_saved_at_rest_and_loaded_at_power_up(tmp_path):
    path = tmp_path / "flash.bin"
    for n in (1, 2):
        booted = boot(EcuParams(), path)
        ecu = Ecu(booted.table.firmware)
        assert logbook_save.load(ecu, booted.payload) == []
        assert ecu.s.log_starts == n - 1  # what the last power-up saved
        saver = logbook_save.boot_saver(ecu, booted)
        _start_and_release(ecu, saver)
        assert saver.saves == 1 and booted.saving is None and booted.sequence == n
        stored = _logbook(path)
        assert stored["log_starts"] == n and stored["log_aborts_stopped"] == n
        assert stored["log_last_shutdown"] == L.SD_OPERATOR_STOP
        assert stored == L.stored_dict(ecu.s)
        booted.flash.close()  # power off


def test_a_power_cut_in_a_save_keeps_the_previous_logbook(tmp_path):
    path = tmp_path / "flash.bin"
    table = ParamTable(EcuParams())
    ecu = Ecu(table.firmware)
    ecu.s.log_runs, ecu.s.log_run_time_s = 3, 120
    FlashImage(path).save(table.stored_image(L.stored_dict(ecu.s)))
    ecu.s.log_runs, ecu.s.log_run_time_s = 4, 180
    image = table.stored_image(L.stored_dict(ecu.s))
    operations = FlashImage(path).writer(image).operations
    assert operations > 3
    for cut in range(operations):  # the process killed after `cut` flash operations
        before = path.read_bytes()
        with FlashImage(path) as flash:
            writer = flash.writer(image)
            for _ in range(cut):
                writer.step()
        booted = boot(EcuParams(), path)
        booted.flash.close()
        fresh = Ecu(booted.table.firmware)
        logbook_save.load(fresh, booted.payload)
        assert (fresh.s.log_runs, fresh.s.log_run_time_s) == (3, 120), f"cut after {cut}"
        assert booted.problems == []
        path.write_bytes(before)
    FlashImage(path).save(image)
    assert _logbook(path)["log_runs"] == 4


def test_an_image_saved_before_the_logbook_still_loads(tmp_path):
    path = tmp_path / "old.bin"
    table = ParamTable(EcuParams(egt_limit_k=1010.0))
    FlashImage(path).save(table.image())  # the set alone, as saves wrote it before
    booted = boot(EcuParams(), path)
    assert booted.state == "loaded" and booted.problems == []
    assert booted.table.params.egt_limit_k == 1010.0
    ecu = Ecu(booted.table.firmware)
    assert logbook_save.load(ecu, booted.payload) == []
    assert set(L.stored_words(ecu.s)) == {0}


def test_xcp_stores_carry_the_logbook_in_python_and_c(tmp_path):
    py_path, c_path = tmp_path / "py.bin", tmp_path / "c.bin"
    rigs = Rigs(flash=(py_path, c_path))
    for s in (rigs.py_ecu.s, rigs.c_ecu.s):
        s.log_runs, s.log_starts, s.log_last_max_egt_dk = 7, 9, 10234
        s.log_aborts[2] = 2
    rigs.same(C.Cmd.CONNECT, 0)
    seed = rigs.same(C.Cmd.GET_SEED, 0, C.RES_CAL_PAG)
    from ecu.xcp.seed_key import key_for

    key = key_for(seed[2:6])
    rigs.same(C.Cmd.UNLOCK, len(key), key)
    assert rigs.same(C.Cmd.SET_REQUEST, 1, 0, 0) == b"\xff"
    for _ in range(40):
        rigs.tick()
    assert py_path.read_bytes() == c_path.read_bytes()
    for path in (py_path, c_path):
        stored = _logbook(path)
        assert (stored["log_runs"], stored["log_starts"]) == (7, 9)
        assert stored["log_aborts_starter_failure"] == 2
        assert stored["log_last_max_egt_dk"] == 10234


def _drive_sil_ecu(impl: str, flash: Path, channel: str, ticks: int) -> dict:
    """`sil ecu --impl IMPL --flash FLASH` on a virtual bus, fed a still engine: armed at tick
    5, released at tick 15 (a start, STOPPED in the spin-up), then at rest; its JSON summary."""
    codec = Codec()
    sensors, analog, demand = codec["PlantSensors"], codec["PlantAnalog"], codec["Demand"]
    actuator = codec["EcuActuator"]
    bus = can.Bus(interface="virtual", channel=channel)
    result: dict = {}
    args = ["ecu", "--impl", impl, "--bus", f"virtual:{channel}", "--flash", str(flash),
            "--ticks", str(ticks), "--json"]  # fmt: skip
    t = threading.Thread(target=lambda: result.setdefault("code", main(args)))
    t.start()

    def put(message, values) -> None:  # noqa: ANN001
        message.pack_raw(values)
        bus.send(can.Message(arbitration_id=message.frame_id, data=message.data,
                             is_extended_id=False))  # fmt: skip

    try:
        raw = [0] * 5
        for k in range(ticks):
            if k % 5 == 0:
                put(demand, [1 if 5 <= k < 15 else 0, 0, 3500, 0, k])
                put(analog, [k, 22200, 0])
            for _ in range(50):  # the ECU may not be listening yet: resend until answered
                put(sensors, [k, 0, 2900])
                reply = bus.recv(0.2)
                while reply is not None and reply.arbitration_id != actuator.frame_id:
                    reply = bus.recv(0.2)
                if reply is not None:
                    actuator.unpack_raw(reply.data, raw)
                    if raw[2] == k:
                        break
        t.join(20)
    finally:
        bus.shutdown()
    assert not t.is_alive() and result["code"] == 0
    return result


@pytest.mark.parametrize("impl", ["python", "c"])
def test_sil_ecu_keeps_the_counts_over_a_restart(impl, tmp_path, capsys):
    flash = tmp_path / "flash.bin"
    for n in (1, 2):
        _drive_sil_ecu(impl, flash, f"logbook_{impl}_{n}", 60)
        summary = json.loads(capsys.readouterr().out)
        assert summary["ticks"] == 60 and summary["mode"] == 0
        stored = _logbook(flash)
        assert stored is not None, f"run {n}: nothing saved"
        assert stored["log_starts"] == n and stored["log_aborts_stopped"] == n
        assert load(flash).sequence == n
