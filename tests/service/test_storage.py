"""Two-slot parameter storage: alternation, fallback to the older slot, a save cut at every
operation, SIGKILL at random points of saves in a writer process, and start-up from flash."""

import os
import random
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from ecu.params import EcuParams
from ecu.service import fault_log
from ecu.service.crc import crc16
from ecu.service.param_table import ParamTable
from ecu.service.port import boot
from ecu.service.storage import (
    HEADER,
    IMAGE_SIZE,
    MAGIC,
    SLOT_SIZE,
    FlashImage,
    StorageError,
    load,
    read_slots,
)
from ecu.service.transport import open_transport
from sil.console.client import ServiceClient, ServiceRequestError
from tests.service.conftest import start_ecu


def test_fresh_image_is_erased_and_saves_alternate(tmp_path):
    path = tmp_path / "flash.bin"
    flash = FlashImage(path)
    assert path.read_bytes() == b"\xff" * IMAGE_SIZE and load(path) is None
    slots = [flash.save(f"set {k}".encode()) for k in range(3)]
    assert [(s.index, s.sequence) for s in slots] == [(0, 1), (1, 2), (0, 3)]
    assert load(path).payload == b"set 2"
    # the layout, read independently: magic, sequence, length, CRC over sequence+length+payload
    raw = path.read_bytes()
    slot1 = raw[SLOT_SIZE : 2 * SLOT_SIZE]
    assert slot1[:4] == MAGIC
    assert int.from_bytes(slot1[4:8], "big") == 2 and int.from_bytes(slot1[8:10], "big") == 5
    assert int.from_bytes(slot1[10:12], "big") == crc16(slot1[4:10] + b"set 1")
    assert slot1[HEADER.size : HEADER.size + 5] == b"set 1"


def test_a_corrupt_newest_slot_falls_back_to_the_older(tmp_path):
    path = tmp_path / "flash.bin"
    flash = FlashImage(path)
    flash.save(b"old")
    flash.save(b"new")
    data = bytearray(path.read_bytes())
    data[SLOT_SIZE + HEADER.size] ^= 0x01  # one bit of slot 1's payload
    path.write_bytes(bytes(data))
    assert [s.index for s in read_slots(path)] == [0]
    assert load(path).payload == b"old"
    assert flash.save(b"next").index == 1  # the next save goes after the newest valid one


def test_a_save_cut_after_any_operation_keeps_the_last_good_set(tmp_path):
    path = tmp_path / "flash.bin"
    FlashImage(path).save(b"good " * 40)
    FlashImage(path).save(b"better " * 40)
    start = path.read_bytes()
    new = bytes(range(256)) * 2
    operations = FlashImage(path).writer(new, page_size=16).operations
    assert operations == 1 + 32 + 1  # erase, 32 pages, header
    for cut in range(operations + 1):
        path.write_bytes(start)
        with FlashImage(path) as flash:  # the process killed after `cut` operations
            writer = flash.writer(new, page_size=16)
            for _ in range(cut):
                writer.step()
        got = load(path)
        if cut < operations:
            assert (got.sequence, got.payload) == (2, b"better " * 40), f"cut after {cut}"
        else:
            assert (got.sequence, got.payload) == (3, new)
        # the save goes to slot 0 (the older set): slot 1 is never touched
        assert path.read_bytes()[SLOT_SIZE:] == start[SLOT_SIZE:]


WRITER = textwrap.dedent(
    """
    import sys
    import time
    from pathlib import Path
    from ecu.params import EcuParams
    from ecu.service.param_table import ParamTable
    from ecu.service.storage import FlashImage

    flash = FlashImage(Path(sys.argv[1]))
    table = ParamTable(EcuParams())
    print("ready", flush=True)
    while True:
        seq = flash.newest().sequence + 1
        params, firmware = table.check_write("pid_kp", (seq % 1000) << 16, False)
        table.commit(params, firmware)
        writer = flash.writer(table.image(), page_size=16)
        print("begin", seq, flush=True)
        while not writer.step():
            time.sleep(0.0002)  # a flash page takes time to program
        print("done", seq, flush=True)
    """
)


KILLS = 40


def test_power_cut_at_random_points_never_loses_the_last_good_set(tmp_path):
    """A writer process saves in a loop and is SIGKILLed after a random delay, 40 times on one
    image: after each cut the image holds the last completed set or the one being written,
    whole, and never nothing."""
    path = tmp_path / "flash.bin"
    FlashImage(path).save(ParamTable(EcuParams()).image())
    rng = random.Random(20261122)
    mid_save = 0
    previous = 1
    for _ in range(KILLS):
        proc = subprocess.Popen(
            [sys.executable, "-c", WRITER, str(path)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        ready = proc.stdout.readline()
        assert ready == "ready\n", f"writer did not start: {ready!r} {proc.stderr.read()}"
        time.sleep(rng.uniform(0.0, 0.02))
        proc.send_signal(signal.SIGKILL)
        out = proc.stdout.read()
        proc.wait()
        proc.stderr.close()
        # the kill can cut the last line short: only whole lines count. A cut "begin" line means
        # no page was written yet; a cut "done" line means the save was complete, which the
        # mid-save branch below accepts as well.
        records = [ln.split() for ln in out.splitlines(keepends=True) if ln.endswith("\n")]
        assert all(len(r) == 2 for r in records), f"unexpected writer output {out[-200:]!r}"
        lines = [token for record in records for token in record]
        done = [int(s) for k, s in records if k == "done"]
        begun = [int(s) for k, s in records if k == "begin"]
        slot = load(path)
        assert slot is not None, f"no valid slot after {lines[-4:]}"
        if begun and (not done or begun[-1] > done[-1]):
            mid_save += 1
            assert slot.sequence in (begun[-1] - 1, begun[-1]), (
                f"{slot.sequence} after {lines[-4:]}"
            )
        else:
            assert slot.sequence == (done[-1] if done else previous), f"after {lines[-4:]}"
        previous = slot.sequence
        loaded = boot(EcuParams(), path)
        assert (loaded.state, loaded.sequence, loaded.problems) == ("loaded", slot.sequence, [])
        expected = 2 << 24 if slot.sequence == 1 else (slot.sequence % 1000) << 16
        assert loaded.table.raw("pid_kp") == expected
        loaded.flash.close()
    print(f"power cuts: {KILLS}, inside a save: {mid_save}, image sequence now {previous}")
    assert mid_save >= KILLS // 4  # most cuts land inside a save: the loop does little else


def test_start_up_without_a_valid_slot_runs_on_defaults_and_flags_it(tmp_path, rig_factory):
    path = tmp_path / "flash.bin"
    with FlashImage(path) as flash:
        flash.save(b"older")
        flash.save(b"newer")
    damaged = bytearray(path.read_bytes())
    for base in (0, SLOT_SIZE):
        damaged[base + HEADER.size] ^= 0x01  # a bit of each set: neither slot valid
    path.write_bytes(bytes(damaged))
    rig = rig_factory(EcuParams(), path)
    ident = rig.client.identify()
    assert (ident["storage"], ident["sequence"]) == ("defaults", None)
    assert ident["param_crc"] == crc16(ParamTable(EcuParams()).image())
    assert [e["name"] for e in rig.client.faults()] == ["PARAMS_DEFAULTS"]
    assert fault_log.PARAMS_DEFAULTS == rig.client.faults()[0]["code"]


def test_save_over_the_port_and_power_up_with_it(tmp_path, rig_factory):
    path = tmp_path / "flash.bin"
    rig = rig_factory(EcuParams(), None)
    with pytest.raises(ServiceRequestError, match="STORAGE: no flash image"):
        rig.client.save()
    rig = rig_factory(EcuParams(), path)
    rig.client.set("pid_kp", 2.5)
    rig.client.set("egt_limit_k", 1200.0)
    saved = rig.client.save()
    assert (saved["slot"], saved["sequence"]) == (0, 1)
    assert rig.client.identify()["storage"] == "loaded"
    rig.client.set("pid_kp", 3.0)
    assert rig.client.save()["slot"] == 1
    rig.boot.flash.close()
    again = rig_factory(EcuParams(), path)  # power cycle
    ident = again.client.identify()
    assert (ident["storage"], ident["slot"], ident["sequence"]) == ("loaded", 1, 2)
    assert again.client.get("pid_kp")["value"] == 3.0
    assert again.ecu.p.egt_limit_dk == 12000
    assert not [e for e in again.client.faults() if e["name"].startswith("PARAMS")]


def test_unusable_image_file_is_named(tmp_path):
    with pytest.raises(StorageError, match="cannot open the flash image"):
        FlashImage(tmp_path / "missing-dir" / "flash.bin")


def test_stored_entries_out_of_limits_are_skipped_and_named(tmp_path):
    import msgpack

    path = tmp_path / "flash.bin"
    FlashImage(path).save(msgpack.packb({"pid_kp": 99 << 24, "bogus": 1, "pid_ki": 3 << 24}))
    b = boot(EcuParams(), path)
    assert b.problems == [
        "pid_kp: stored value 1660944384 outside its limits, skipped",
        "'bogus': not a parameter of this firmware, skipped",
    ]
    assert (b.table.raw("pid_kp"), b.table.raw("pid_ki")) == (2 << 24, 3 << 24)


class PowerCut(Exception):
    pass


ECU_CUTS = 6


def test_power_cut_of_the_ecu_process_during_saves_over_the_port(tmp_path):
    """`sil ecu --serial pty --flash` is SIGKILLed at a seeded random moment while a client writes
    and saves parameters in a loop; after each restart the ECU powers up with the last set whose
    save was confirmed, or the one whose save was under way, never less."""
    flash = tmp_path / "flash.bin"
    rng = random.Random(7)
    confirmed: tuple[int | None, float] = (None, 2.0)  # (sequence, pid_kp) last confirmed
    in_flight: float | None = None  # pid_kp of a save sent but not confirmed
    outcomes = {"save under way completed": 0, "last confirmed set": 0}
    cuts_in_a_save = 0
    for cut in range(ECU_CUTS + 1):
        ecu, port = start_ecu(flash, f"cut{cut}")
        client = ServiceClient(open_transport(port), timeout_s=5.0, retries=0)
        ident = client.identify()
        kp = client.get("pid_kp")["value"]
        if in_flight is not None and ident["sequence"] != confirmed[0]:
            outcomes["save under way completed"] += 1
            assert (ident["sequence"], kp) == ((confirmed[0] or 0) + 1, in_flight)
            confirmed = (ident["sequence"], kp)
        else:
            outcomes["last confirmed set"] += 1
            assert (ident["sequence"], kp) == confirmed
            assert ident["storage"] == ("defaults" if confirmed[0] is None else "loaded")
        if cut == ECU_CUTS:
            ecu.send_signal(signal.SIGTERM)
            ecu.communicate(timeout=30)
            break
        kill_at = time.monotonic() + rng.uniform(0.1, 1.0)

        def idle(ecu: subprocess.Popen = ecu, kill_at: float = kill_at) -> None:
            if time.monotonic() >= kill_at:
                ecu.send_signal(signal.SIGKILL)
                raise PowerCut
            time.sleep(0.001)

        client.idle = idle
        in_flight = None
        try:
            while True:
                value = 1.0 + rng.randrange(64) / 16
                client.set("pid_kp", value)
                in_flight = value
                saved = client.save()
                confirmed, in_flight = (saved["sequence"], value), None
        except PowerCut:
            ecu.wait()
            cuts_in_a_save += in_flight is not None
        client.transport.close()
    print(f"ECU power cuts: {ECU_CUTS}, {cuts_in_a_save} while a save was under way; {outcomes}")
    assert cuts_in_a_save >= 1  # the seeded moments do hit saves


def test_a_flash_write_error_is_answered_and_the_port_goes_on(tmp_path, rig_factory):
    rig = rig_factory(EcuParams(), tmp_path / "flash.bin")
    read_only = os.open(tmp_path / "flash.bin", os.O_RDONLY)
    os.dup2(read_only, rig.boot.flash.fd)  # the flash fails under the ECU: it reads, writes fail
    os.close(read_only)
    with pytest.raises(ServiceRequestError, match="STORAGE: flash write failed: .*Bad file"):
        rig.client.save()
    assert rig.client.identify()["storage"] == "defaults"
