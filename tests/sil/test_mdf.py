"""MF4 bus logs (sil/record/mdf.py, `sil log convert`, `sil replay` of an MF4): the ASAM bus-logging
layout with the absolute start in the header and the time axis from it; asammdf decodes a run's
MF4 with the DBC to the run's trace.csv; frames, times and channels survive the trip to MF4 and
back; a damaged MF4 is named in one line, as the other formats are."""

from __future__ import annotations

import csv
import io
import json
import random
import re
import time
from contextlib import redirect_stderr
from datetime import UTC, datetime
from pathlib import Path

import can
import numpy as np
import pytest

from protocol.bus import open_bus
from protocol.codec import Codec
from sil.record import mdf as mdf_tools
from sil.record import replay
from sil.record.canlog import CandumpWriter, LogReadError, convert_log, detect_format, read_frames

asammdf = pytest.importorskip("asammdf")

DBC = Path(__file__).resolve().parents[2] / "protocol" / "turbojet.dbc"
START = datetime(2026, 3, 4, 5, 6, 7, 890123, tzinfo=UTC)
# every message of the contract but SimRun (never recorded): a start from rest, a fault, a stop
SCENARIO = """
description = "A start from rest, a fault and a stop, 30 s"
duration_s = 30
[plant]
model = "aero"
standstill = true
[controller]
kind = "mrac"
preset = "default"
[command]
base = 60
stop_s = 22
[[fault]]
time_s = 12
target = "PUMP_EFFECTIVENESS"
value = 0.9
"""


def _our_log(path: Path, ticks: int = 50, t0: float = 0.0) -> Path:
    codec = Codec()
    writer = CandumpWriter(path)
    for k in range(ticks):
        for name, values in (
            ("PlantSensors", [k, 100_000 + k, 1000.0]),
            ("EcuActuator", [1, 2, k, 40.0, 5.0]),
        ):
            m = codec[name]
            m.pack(values)
            writer.write(t0 + k * 0.001, m.frame_id, m.data)
    writer.close()
    return path


def _mixed() -> list[can.Message]:
    """Data frames (standard, extended, CAN FD), remote and error frames on two channels."""
    return [
        can.Message(timestamp=0.0, arbitration_id=0x100, data=bytes(range(8)), channel="vcan0"),
        can.Message(timestamp=0.001, arbitration_id=0x1ABCDE, is_extended_id=True,
                    data=b"\x01\x02", channel="vcan0"),
        can.Message(timestamp=0.002, arbitration_id=0x123, is_fd=True, bitrate_switch=True,
                    data=bytes(range(24)), channel="can1"),
        can.Message(timestamp=0.003, arbitration_id=0x200, is_remote_frame=True, dlc=4,
                    channel="vcan0"),
        can.Message(timestamp=0.004, arbitration_id=0x0, is_error_frame=True, channel="can1"),
        can.Message(timestamp=0.005, arbitration_id=0x101, data=b"", channel="vcan0",
                    is_rx=False),
    ]  # fmt: skip


def _same_frame(a: can.Message, b: can.Message) -> None:
    assert b.timestamp == pytest.approx(a.timestamp, abs=1e-9)
    for attr in ("arbitration_id", "is_extended_id", "is_remote_frame", "is_error_frame",
                 "is_fd", "bitrate_switch", "channel", "is_rx"):  # fmt: skip
        assert getattr(b, attr) == getattr(a, attr), (attr, a, b)
    if not a.is_remote_frame:
        assert bytes(b.data) == bytes(a.data)
    else:
        assert b.dlc == a.dlc


def test_every_kind_of_frame_survives_mf4_with_the_absolute_start(tmp_path):
    from sil.record import mdf

    frames = _mixed()
    base = mdf.TimeBase(round(START.timestamp() * 1e6), True, "a test")
    path = tmp_path / "mixed.mf4"
    mdf.write_bus_log(path, mdf.FrameTable.of(frames), base)
    assert detect_format(path) == ("mf4", False)
    back = list(read_frames(path))
    assert len(back) == len(frames)
    for a, b in zip(frames, back, strict=True):
        _same_frame(a, b)

    # as a tool sees it: the ASAM layout, the start in the header, the time axis from 0
    m = asammdf.MDF(path)
    assert m.header.start_time == START
    groups = {
        (g.channel_group.acq_source.name, g.channels[1].name): g.channel_group for g in m.groups
    }
    assert set(groups) == {
        ("vcan0", "CAN_DataFrame"), ("vcan0", "CAN_RemoteFrame"), ("can1", "CAN_DataFrame"),
        ("can1", "CAN_ErrorFrame"),
    }  # fmt: skip
    names = [c.name for c in m.groups[0].channels]
    assert names[:1] == ["time"] and {"CAN_DataFrame.ID", "CAN_DataFrame.DLC",
        "CAN_DataFrame.DataLength", "CAN_DataFrame.DataBytes"} <= set(names)  # fmt: skip
    assert m.get("CAN_DataFrame", 0).timestamps[0] == 0.0
    m.close()

    # python-can's own MF4 reader gives the same frames, at their absolute times
    with can.MF4Reader(str(path)) as reader:
        theirs = sorted(reader, key=lambda x: x.timestamp)
    assert [x.arbitration_id for x in theirs] == [f.arbitration_id for f in frames]
    assert theirs[0].timestamp == pytest.approx(START.timestamp(), abs=1e-6)


def test_epoch_times_start_at_their_first_frame_and_come_back_as_they_were(tmp_path):
    """A bench's candump -L (epoch times): the MF4 starts at its first frame, its axis from 0
    (python-can's logconvert gives an axis of the epoch's seconds below 0); back, the file."""
    t0 = 1_780_000_000.123456
    log = _our_log(tmp_path / "bench.log", ticks=40, t0=t0)
    done = convert_log(log, tmp_path / "bench.mf4")
    assert done["source_times"] == "epoch" and done["start_from"] == "the log's first frame"
    m = asammdf.MDF(tmp_path / "bench.mf4")
    assert m.header.start_time.timestamp() == pytest.approx(t0, abs=1e-6)
    t = m.get("CAN_DataFrame", 0).timestamps
    assert t[0] == 0.0 and t[-1] == pytest.approx(0.039, abs=1e-6)  # (epoch floats)
    m.close()
    convert_log(tmp_path / "bench.mf4", tmp_path / "back.log")
    assert (tmp_path / "back.log").read_bytes() == log.read_bytes()


def test_python_cans_mf4_of_a_runs_log_gets_its_axis_from_0(tmp_path):
    """python-can's MF4Writer (`python -m can.logconvert can.log x.mf4`) puts a run's times
    against the time of the conversion: an axis near -1.8e9 s. Converted again, the frames
    count from the file's start, the axis from 0."""
    theirs = tmp_path / "theirs.mf4"
    writer = can.MF4Writer(str(theirs))
    for m in read_frames(_our_log(tmp_path / "can.log", ticks=20)):
        writer.on_message_received(m)
    writer.stop()
    m = asammdf.MDF(theirs)
    assert m.get("CAN_DataFrame", 0).timestamps[0] < -1e9
    m.close()
    done = convert_log(theirs, tmp_path / "ours.mf4")
    assert done["source_times"] == "from the start" and done["start_from"] == "the MF4"
    m = asammdf.MDF(tmp_path / "ours.mf4")
    t = m.get("CAN_DataFrame", 0).timestamps
    assert t[0] == pytest.approx(0.0, abs=1e-6) and t[-1] == pytest.approx(0.019, abs=1e-6)
    assert abs(m.header.start_time.timestamp() - time.time()) < 600
    m.close()


def test_a_relative_log_takes_its_start_from_the_run_folder_or_start(tmp_path):
    log = _our_log(tmp_path / "can.log")
    (tmp_path / "run.json").write_text("{}")
    done = convert_log(log, tmp_path / "can.mf4")
    assert done["start_from"] == "the run's start (run.json)"
    assert done["source_times"] == "from the start"
    given = convert_log(log, tmp_path / "given.mf4", start_s=START.timestamp())
    assert given["start"] == "2026-03-04T05:06:07.890123Z" and given["start_from"] == "--start"
    # to a format with a date in its header, the frames get their absolute times
    convert_log(tmp_path / "given.mf4", tmp_path / "given.asc")
    asc = (tmp_path / "given.asc").read_text()
    assert re.search(r"Begin Triggerblock \w+ Mar 04 \d\d:06:07\.890 2026", asc), asc[:300]
    back = convert_log(tmp_path / "given.asc", tmp_path / "asc.mf4")
    assert back["start_from"] == "the log's header"
    assert abs(datetime.fromisoformat(back["start"]).timestamp() - START.timestamp()) < 1e-3


def test_an_mf4_plays_onto_a_bus(tmp_path):
    path = tmp_path / "play.mf4"
    convert_log(_our_log(tmp_path / "play.log", ticks=100), path)
    with open_bus("virtual:mdf_play") as tx, open_bus("virtual:mdf_play") as rx:
        report = replay.play(path, tx)
        got = []
        while (m := rx.recv(0.1)) is not None:
            got.append(m)
    assert report.sent == 200 and len(got) == 200
    assert report.duration_s >= 0.099
    assert [bytes(m.data) for m in got] == [bytes(m.data) for m in read_frames(path)]


def test_a_cut_or_corrupt_mf4_is_one_error_naming_the_file_and_byte(tmp_path, capfd):
    """Cut anywhere, or one byte changed anywhere: frames, or a LogReadError naming the file
    and the byte (the block structure is checked before asammdf reads it); nothing on stderr."""
    path = tmp_path / "whole.mf4"
    convert_log(_our_log(tmp_path / "whole.log", ticks=200), path)
    data = path.read_bytes()
    damaged = tmp_path / "damaged.mf4"
    rng = random.Random(7)
    outcomes: dict[str, int] = {}
    sizes = range(1, len(data), max(1, len(data) // 100))
    flips = [rng.randrange(len(data)) for _ in range(100)]
    for kind, cases in (("cut", sizes), ("flip", flips)):
        for n in cases:
            if kind == "cut":
                damaged.write_bytes(data[:n])
            else:
                damaged.write_bytes(data[:n] + bytes([data[n] ^ 0xFF]) + data[n + 1 :])
            try:
                count = sum(1 for _ in read_frames(damaged))
            except LogReadError as exc:
                assert str(exc).startswith(f"{damaged}: "), str(exc)
                assert re.fullmatch(r"(byte|frame|line) \d+", exc.position), str(exc)
                outcomes[f"{kind} error"] = outcomes.get(f"{kind} error", 0) + 1
            else:
                assert kind == "flip" and count <= 400
    assert outcomes["cut error"] == len(sizes)
    assert capfd.readouterr().err == ""
    damaged.write_bytes(data[: len(data) - 10])
    with pytest.raises(LogReadError, match=rf"damaged.mf4: byte {len(data) - 10}: truncated MF4"):
        list(read_frames(damaged))


def _trace(path: Path) -> tuple[dict[str, int], np.ndarray]:
    with path.open() as f:
        rows = list(csv.reader(f))
    column = {h.split("[")[0]: k for k, h in enumerate(rows[0])}
    return column, np.array([[float(x) for x in r] for r in rows[1:]])


@pytest.mark.slow
def test_asammdf_decodes_a_runs_mf4_with_the_dbc_to_its_trace(tmp_path, sil):
    """A run (in process) from rest, with a fault and a stop; `sil log convert` makes its MF4;
    asammdf's MDF.extract_bus_logging decodes it with the DBC, and every signal at every tick
    it was sent is trace.csv's value there (the trace holds a tick's last frame), within half
    the DBC's resolution (and the trace's 9 significant digits). The MF4 starts at the run's
    tick 0 on the wall clock, its axis at the run's time 0; back to candump it is can.log."""
    scenario = tmp_path / "short.toml"
    scenario.write_text(SCENARIO)
    out = tmp_path / "run"
    done = sil("run", str(scenario), "--mode", "inproc", "--out", str(out), "--no-plots")
    assert done.returncode == 0, done.stderr
    converted = sil("log", "convert", str(out / "can.log"), str(out / "can.mf4"), "--json")
    assert converted.returncode == 0, converted.stderr
    report = json.loads(converted.stdout)
    assert report["start_from"] == "the run's tick 0 (summary.json)"

    mdf = asammdf.MDF(out / "can.mf4")
    started = mdf_tools.parse_start(json.loads((out / "summary.json").read_text())["tick0_utc"])
    assert mdf.header.start_time.timestamp() == pytest.approx(started, abs=1e-6)
    assert (out / "run.json").stat().st_mtime <= started
    decoded = mdf.extract_bus_logging({"CAN": [(str(DBC), 0)]})
    assert decoded.header.start_time == mdf.header.start_time

    column, trace = _trace(out / "trace.csv")
    ticks = trace[:, column["tick"]].astype(int)
    assert (ticks == np.arange(len(ticks))).all()
    codec = Codec()
    scale = {s.name: s.scale for m in codec.database.messages for s in m.signals}
    worst: dict[str, float] = {}
    for group in decoded.groups:
        for channel in group.channels[1:]:
            name = channel.name
            if name.endswith(("_CRC", "_Counter")) or name in worst:
                continue
            signal = decoded.get(name)
            if signal.samples.dtype.kind in "SUO":  # a value table: its numbers
                signal = decoded.get(name, raw=True)
            tick = np.floor(signal.timestamps / 0.01 + 1e-6).astype(int)
            last = np.r_[tick[1:] != tick[:-1], True]  # a tick's last frame is the trace's
            tick, value = tick[last], signal.samples[last].astype(float)
            # EcuTelemetry's multiplexer: index k % 13 at tick k (the trace keeps no column)
            expected = tick % 13 if name == "TelemetryIndex" else trace[tick, column[name]]
            assert not np.isnan(expected).any(), name
            difference = np.abs(value - expected)
            bound = scale[name] / 2 + 5e-9 * np.abs(expected)
            assert (difference <= bound).all(), (name, difference.max(), scale[name])
            worst[name] = float(difference.max())
    signals = set(column) - {"time", "tick", "command", "speed_true", "speed_meas"}
    assert set(worst) == signals - {"RunId", "RunTick"}  # (SimRun is never recorded)
    print("largest difference per signal:", json.dumps(worst))
    mdf.close()

    # back to candump: can.log, byte for byte
    assert sil("log", "convert", str(out / "can.mf4"), str(tmp_path / "back.log")).returncode == 0
    assert (tmp_path / "back.log").read_bytes() == (out / "can.log").read_bytes()


@pytest.mark.slow
def test_a_runs_mf4_replays_as_the_log_it_came_from(tmp_path, sil):
    """`sil run --log-format mf4` writes can.mf4 beside can.log, starting at the run's
    wall-clock start (and a run into the folder without it clears it). --dry-run of it reports
    what the can.log gives; --into-ecu of it finds no difference; back to candump it is can.log.
    Damaged, `sil replay`, `sil identify` and `sil log convert` name the file and the byte in
    one line (replay after the report of what it read: exit 1, as for the other formats;
    identify and convert refuse it: exit 2)."""
    out = tmp_path / "run"
    before = time.time()
    done = sil("run", "accel-idle-to-max", "--mode", "inproc", "--out", str(out), "--no-plots",
                "--log-format", "mf4")  # fmt: skip
    assert done.returncode == 0, done.stderr
    m = asammdf.MDF(out / "can.mf4")
    start = m.header.start_time.timestamp()
    m.close()
    assert (out / "run.json").stat().st_mtime <= start <= (out / "summary.json").stat().st_mtime
    assert before < start
    assert sil("log", "convert", str(out / "can.mf4"), str(tmp_path / "back.log")).returncode == 0
    assert (tmp_path / "back.log").read_bytes() == (out / "can.log").read_bytes()
    dry_log = sil("replay", "--dry-run", "--json", str(out / "can.log"))
    dry_mf4 = sil("replay", "--dry-run", "--json", str(out / "can.mf4"))
    assert dry_mf4.returncode == 0, dry_mf4.stderr
    assert json.loads(dry_mf4.stdout) == json.loads(dry_log.stdout)
    text = sil("replay", "--dry-run", str(out / "can.mf4")).stdout.splitlines()
    assert text[0] == sil("replay", "--dry-run", str(out / "can.log")).stdout.splitlines()[0]
    into = sil("replay", "--into-ecu", "--json", str(out / "can.mf4"))
    assert into.returncode == 0, into.stderr
    result = json.loads(into.stdout)
    assert result["frames_compared"] > 1000 and result["frames_differing"] == 0
    assert result["run_record"] == str(out / "run.json")

    data = (out / "can.mf4").read_bytes()
    cut = tmp_path / "cut.mf4"
    cut.write_bytes(data[:-100])
    where = f"{cut}: byte {len(data) - 100}: truncated MF4"
    dry = sil("replay", "--dry-run", "--json", str(cut))
    assert dry.returncode == 1 and dry.stderr.startswith(f"sil replay: {where}")
    assert len(dry.stderr.splitlines()) == 1
    assert json.loads(dry.stdout)["error"].startswith(where)
    for command, code in (("replay", 1), ("identify", 2), ("log", 2)):
        args = {"replay": ("--into-ecu", "--scenario", "accel-idle-to-max"), "identify": (),
                "log": ("convert",)}[command]  # fmt: skip
        extra = (str(tmp_path / "x.log"),) if command == "log" else ()
        result = sil(command, *args, str(cut), *extra)
        name = "log convert" if command == "log" else command
        assert result.returncode == code, (command, result.stderr)
        assert result.stderr.startswith(f"sil {name}: {where}"), result.stderr
        assert len(result.stderr.splitlines()) == 1, result.stderr
    assert not (tmp_path / "x.log").exists()

    # the next run into the folder, without --log-format mf4, leaves no MF4 of the last one
    done = sil("run", "accel-idle-to-max", "--mode", "inproc", "--out", str(out), "--no-plots")
    assert done.returncode == 0, done.stderr
    assert not (out / "can.mf4").exists()


def test_no_asammdf_noise_reaches_stderr_on_a_file_that_is_no_mf4(tmp_path):
    """MDF 3 and files that only start like MDF: named, not handed to asammdf's logging."""
    mdf3 = tmp_path / "old.mdf"
    mdf3.write_bytes(b"MDF     3.30    " + bytes(48))
    with pytest.raises(LogReadError, match=r"old.mdf: byte 8: MDF 3.30: a CAN bus log is MDF 4"):
        list(read_frames(mdf3))
    fake = tmp_path / "fake.mf4"
    fake.write_bytes(b"MDF     4.10    " + bytes(48) + b"##HD" + bytes(20))
    err = io.StringIO()
    with redirect_stderr(err), pytest.raises(LogReadError, match=r"fake.mf4: byte \d+: "):
        list(read_frames(fake))
    assert err.getvalue() == ""
