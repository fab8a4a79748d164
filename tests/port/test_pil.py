"""Processor in the loop: the firmware image (ecu_main.c on board_mps2.c) on QEMU's mps2-an386
answers as the C node does on both its CAN links (Ethernet; slcan on its UART, where it looks like
a USB-CAN adapter to python-can's slcan interface), refuses a bad calibration block, and flies a
scenario with a can.log byte-identical to the C ECU's."""

from __future__ import annotations

import json
import struct
import subprocess
import time
import zlib

import can
import pytest

from ecu.firmware_params import compile_params
from ecu.params import preset
from ecu.port import build
from ecu.port.core import make_ecu
from ecu.port.node import CEcuNode
from ecu.port.pil import PilError, PilImage, calibration_block, image_sizes
from plant.fast_plant import FastPlant
from plant.interface import PlantConfig
from plant.node import PlantNode
from sil.bench import port as port_bench
from tests.port.test_sil import _run


@pytest.fixture(scope="module")
def image(toolchains):
    """The image with its CAN on Ethernet (the default link)."""
    return build.arm_pil_image("eth")


@pytest.fixture(scope="module")
def slcan_image(toolchains):
    return build.arm_pil_image("slcan")


@pytest.fixture(scope="module")
def params():
    return compile_params(preset("default"))


def _plant_frames(count: int) -> list[tuple[int, bytes]]:
    """The plant's first frames (tick 0: truth, PlantAnalog, PlantSensors)."""
    frames: list[tuple[int, bytes]] = []
    node = PlantNode(FastPlant(PlantConfig(ecu_period_s=0.01)))
    node.start(lambda i, d: frames.append((i, bytes(d))))
    return frames[:count]


def _closed_loop(params, ticks: int) -> list[tuple[list, list]]:
    """The plant's frames of each tick and the C node's answers, the loop closed here."""
    plant = PlantNode(FastPlant(PlantConfig(ecu_period_s=0.01)))
    c_node = CEcuNode(make_ecu("c", params), lockstep=True)
    out: list[tuple[list, list]] = []
    frames: list[tuple[int, bytes]] = []
    plant.start(lambda i, d: frames.append((i, bytes(d))))
    for _ in range(ticks):
        answers: list[tuple[int, bytes]] = []
        for frame_id, data in frames:
            c_node.on_frame(frame_id, data, lambda i, d, a=answers: a.append((i, bytes(d))))
        out.append((frames, answers))
        frames = []
        for frame_id, data in answers:
            plant.on_frame(frame_id, data, lambda i, d, f=frames: f.append((i, bytes(d))))
    return out


def _c_node_answers(params, frames: list[tuple[int, bytes]]) -> list[tuple[int, bytes]]:
    expected: list[tuple[int, bytes]] = []
    c_node = CEcuNode(make_ecu("c", params), lockstep=True)
    for frame_id, data in frames:
        c_node.on_frame(frame_id, data, lambda i, d: expected.append((i, bytes(d))))
    assert expected, "the C node answers tick 0"
    return expected


def _exchange(bus: can.BusABC, frames: list[tuple[int, bytes]], count: int) -> list:
    """Send ``frames``; the first ``count`` frames heard back (or fewer after 5 s of silence)."""
    for frame_id, data in frames:
        bus.send(can.Message(arbitration_id=frame_id, is_extended_id=False, data=data))
    got = []
    while len(got) < count and (msg := bus.recv(5.0)) is not None:
        got.append((msg.arbitration_id, bytes(msg.data)))
    return got


def test_image_answers_python_can_slcan_as_the_c_node_does(slcan_image, params):
    frames = _plant_frames(10)
    expected = _c_node_answers(params, frames)
    with PilImage(calibration_block(params, lockstep=True), link="slcan", elf=slcan_image) as pil:
        bus = can.Bus(interface="slcan", channel=pil.url, sleep_after_open=0)
        try:
            pil.wait_ready()
            assert bus.get_version(2.0) == (10, 13)  # "V1013": an adapter's answer
            got = _exchange(bus, frames, len(expected))
        finally:
            bus.shutdown()
    assert got == expected


def test_image_answers_on_its_ethernet_link_as_the_c_node_does(image, params):
    ticks = _closed_loop(params, 3)  # the plant's frames and the C node's answers, tick by tick
    got = []
    with PilImage(calibration_block(params, lockstep=True), elf=image) as pil:
        assert pil.url.startswith("udp://127.0.0.1:")  # loopback only
        bus = pil.open_bus()
        try:
            pil.wait_ready()
            for frames, answers in ticks:
                got.append(_exchange(bus, frames, len(answers)))
                # a frame of another EtherType and a runt: dropped by the image, not taken
                bus._sock.sendto(b"\xff" * 6 + b"\x02" * 6 + b"\x08\x00" + bytes(46), bus._peer)
                bus._sock.sendto(b"\xff" * 6, bus._peer)
        finally:
            bus.shutdown()
    assert all(answers for _, answers in ticks) and got == [answers for _, answers in ticks]


@pytest.mark.parametrize(
    ("spoil", "reason"),
    [
        (lambda b: b[:-1] + bytes([b[-1] ^ 1]), "CRC mismatch"),
        (lambda b: b"XXXX" + b[4:], "no ECUC magic"),
        (lambda b: b[:4] + struct.pack("<I", 99) + b[8:], "version not supported"),
        (lambda b: b[:40], "CRC mismatch"),  # a half-written block: the flash reads 0 beyond
    ],
)
def test_image_refuses_a_bad_calibration_block(image, params, spoil, reason):
    with PilImage(spoil(calibration_block(params, lockstep=True)), elf=image) as pil:
        bus = pil.open_bus()
        try:
            with pytest.raises(PilError, match=reason):
                pil.wait_ready(10.0)
        finally:
            bus.shutdown()


def test_image_refuses_parameters_the_core_refuses(image, params):
    block = bytearray(calibration_block(params, lockstep=True))
    struct.pack_into("<i", block, 24, 0)  # the first parameter word, rate_hz: 0
    body = bytes(block[:-4])
    with PilImage(body + struct.pack("<I", zlib.crc32(body)), elf=image) as pil:
        bus = pil.open_bus()
        try:
            with pytest.raises(PilError, match="refused by ecu_params_load"):
                pil.wait_ready(10.0)
        finally:
            bus.shutdown()


@pytest.mark.parametrize("link", ["eth", "slcan"])
def test_image_has_no_heap_and_fits_a_small_part(toolchains, link):
    elf = build.arm_pil_image(link)
    symbols = subprocess.run(
        ["arm-none-eabi-nm", str(elf)], capture_output=True, text=True, check=True
    ).stdout
    assert "malloc" not in symbols and "_sbrk" not in symbols
    sizes = image_sizes(elf)
    assert 0 < sizes["flash_bytes"] <= 32 * 1024 and 0 < sizes["ram_bytes"] <= 16 * 1024


@pytest.mark.slow
@pytest.mark.parametrize("link", ["eth", "slcan"])
def test_pil_lockstep_can_log_is_byte_identical_and_counts_instructions(
    tmp_path, first_difference, vectors, toolchains, link, sil, udp_spec
):
    pil_log = _run(sil, tmp_path, "pil", "--bus", udp_spec(), "--pil-link", link)
    c_log = _run(sil, tmp_path, "c", "--bus", udp_spec())
    assert len(c_log.splitlines()) > 1000
    assert first_difference(pil_log, c_log) is None
    summary = json.loads(next(tmp_path.glob("pil-*")).joinpath("summary.json").read_text())
    figures = summary["pil"]
    assert figures["ticks_profiled"] >= 250 and figures["watchdog_resets"] == 0
    # the core's instructions per tick in the loop, against the golden vectors' figure
    path, g = vectors["mrac-aero"]
    golden = port_bench.qemu_instructions(path, g.ticks)
    assert isinstance(golden, float), golden
    in_loop = figures["instructions_per_tick"]["core_mean"]
    assert abs(in_loop / golden - 1.0) <= 0.05, (in_loop, golden)
    load = figures["cpu_load_pct"]
    assert load["1_kHz"] == pytest.approx(10 * load["100_Hz"], rel=1e-2)


def test_watchdog_resets_a_stuck_image(image, params):
    frames = _plant_frames(10)
    expected = _c_node_answers(params, frames)
    with PilImage(calibration_block(params, lockstep=True), elf=image) as pil:
        bus = pil.open_bus()
        try:
            pil.wait_ready()
            assert pil.profile.resets == 0
            pil.console("WDTEST")  # the main loop stops kicking
            deadline = time.monotonic() + 20.0
            while pil.profile.resets == 0 and time.monotonic() < deadline:
                time.sleep(0.01)
            assert pil.profile.resets == 1, pil.profile.lines
            pil.wait_ready(10.0)  # it boots again, checks its block and flies from tick 0
            assert _exchange(bus, frames, len(expected)) == expected
        finally:
            bus.shutdown()


def test_image_answers_xcp_as_the_c_node_does(image):
    """The image's XCP slave (its calibration block's IDs, seed and run record) and the C node's,
    fed the same master frames (before the plant: answered at once; then at the tick boundary) and
    plant frames: the same frames out, XCP answers and DTOs before each tick's own frames."""
    from ecu.params import EcuParams
    from ecu.port.pil import XcpBlock
    from ecu.port.xcp import CXcpSlave
    from ecu.port.xcp_run import run_record
    from ecu.service.port import boot
    from ecu.xcp import codes as C
    from ecu.xcp import memory as MEM
    from ecu.xcp.seed_key import key_for
    from protocol.codec import Codec

    booted = boot(EcuParams(), None)
    seed = 0x1234567
    block = calibration_block(
        booted.table.firmware,
        lockstep=True,
        xcp=XcpBlock((0x700, 0x701), seed, run_record(booted.table)),
    )
    ecu = make_ecu("c", booted.table.firmware)
    node = CEcuNode(ecu, lockstep=True)
    node.attach_xcp(CXcpSlave(ecu, booted.table, seed=seed))
    codec = Codec()
    sensors, analog = codec["PlantSensors"], codec["PlantAnalog"]

    def plant(tick: int) -> list[tuple[int, bytes]]:
        out = []
        if tick % 5 == 0:
            analog.pack_raw((tick, 22_200, 1_500))
            out.append((analog.frame_id, bytes(analog.data)))
        sensors.pack_raw((tick, 100_890 + (tick * 37) % 200, 10_480))
        return [*out, (sensors.frame_id, bytes(sensors.data))]

    def c_answers(frames: list[tuple[int, bytes]]) -> list[tuple[int, bytes]]:
        got: list[tuple[int, bytes]] = []
        for frame_id, data in frames:
            node.on_frame(frame_id, data, lambda i, d: got.append((i, bytes(d))))
        return got

    daq = [bytes((C.Cmd.FREE_DAQ,)), bytes((C.Cmd.ALLOC_DAQ, 0, 1, 0)),
           bytes((C.Cmd.ALLOC_ODT, 0, 0, 0, 2)), bytes((C.Cmd.ALLOC_ODT_ENTRY, 0, 0, 0, 0, 1)),
           bytes((C.Cmd.ALLOC_ODT_ENTRY, 0, 0, 0, 1, 3)), bytes((C.Cmd.SET_DAQ_PTR, 0, 0, 0, 0, 0)),
           struct.pack("<BBBBI", C.Cmd.WRITE_DAQ, 0xFF, 1, 0, MEM.measurement_address(1)),
           bytes((C.Cmd.SET_DAQ_PTR, 0, 0, 0, 1, 0))]  # fmt: skip
    for name in ("ticks", "egt", "pump_enable"):  # 7 bytes
        k = MEM.MEAS_INDEX[name]
        size = MEM.MEASUREMENTS[k].size
        daq.append(
            struct.pack("<BBBBI", C.Cmd.WRITE_DAQ, 0xFF, size, 0, MEM.measurement_address(k))
        )
    daq += [struct.pack("<BBHHBB", C.Cmd.SET_DAQ_LIST_MODE, 0x10, 0, 0, 1, 0),
            bytes((C.Cmd.START_STOP_DAQ_LIST, 1, 0, 0))]  # fmt: skip
    with PilImage(block, elf=image) as pil:
        bus = pil.open_bus()
        try:
            pil.wait_ready()

            def exchange(frames: list[tuple[int, bytes]], until_tick: bool) -> list:
                for frame_id, data in frames:
                    bus.send(can.Message(arbitration_id=frame_id, is_extended_id=False, data=data))
                got = []
                while (msg := bus.recv(5.0)) is not None:
                    got.append((msg.arbitration_id, bytes(msg.data)))
                    if not until_tick or msg.arbitration_id == 0x110:
                        break
                return got

            before = [bytes((C.Cmd.CONNECT, 0)), bytes((C.Cmd.GET_SEED, 0, C.RES_DAQ))]
            for frame in before:
                answer = exchange([(0x700, frame)], until_tick=False)
                assert answer == c_answers([(0x700, frame)]), frame.hex()
            key = key_for(answer[0][1][2:6])
            master = {
                0: [bytes((C.Cmd.UNLOCK, 2)) + key],
                **{1 + k: [f] for k, f in enumerate(daq)},
            }
            master[30] = [struct.pack("<BBBBI", C.Cmd.SHORT_UPLOAD, 4, 0, 0, MEM.CAL_BASE + 60)]
            master[31] = [bytes((C.Cmd.GET_STATUS,)), bytes((C.Cmd.GET_DAQ_CLOCK,))]
            seen = 0
            for tick in range(40):
                frames = [(0x700, f) for f in master.get(tick, [])] + plant(tick)
                got = exchange(frames, until_tick=True)
                assert got == c_answers(frames), tick
                seen += sum(1 for i, d in got if i == 0x701 and d[0] < C.PID_SERV)
            assert seen > 40  # DTOs of two ODTs on every tick since the list started
        finally:
            bus.shutdown()
