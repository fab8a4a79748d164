"""One time base and python-can's conventions for the logs of a run: every log format a run
writes starts at its tick 0 (the ASC's trigger block, the BLF's frames, the MF4's header) and so
does `sil log convert` of its can.log; a frame's channel is the bus's; a log of several
channels, whatever they are named, converts to every format python-can writes, with our
converter and with python-can's own."""

from __future__ import annotations

import json
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

import can
import pytest

from sil.record import mdf
from sil.record.canlog import numbered_channels

asammdf = pytest.importorskip("asammdf")

# a capture of the loopback bus from before frames carried the bus's channel (a sender token
# each), a group address as channel (can.logger on the bus today) and a numbered interface
MIXED = (
    "(1.000000) udp-8acf5c733522 100#0011223344556677\n"
    "(1.010000) udp-0123456789ab 101#0011\n"
    "(1.020000) 239.255.1.2 102#00\n"
    "(1.030000) can1 103#01\n"
    "(1.040000) udp-8acf5c733522 100#0011223344556678\n"
)


def _msg(channel: object) -> can.Message:
    return can.Message(arbitration_id=0x100, data=b"\x01", is_extended_id=False, channel=channel)


def test_channels_are_numbered_as_the_formats_number_them() -> None:
    names = ["udp-8acf5c733522", "vcan0", "can1", "239.255.1.2", None, "udp-8acf5c733522",
             "can0", 5, "can70"]  # fmt: skip
    got = [m.channel for m in numbered_channels(_msg(c) for c in names)]
    # in order of appearance: the token takes 0 and keeps it; vcan0's 0 and can1's 1 are taken,
    # so they take the next free; 5 is free, can70 beyond the formats' range
    assert got == [0, 1, 2, 3, None, 0, 4, 5, 6]
    assert [m.channel for m in numbered_channels(_msg(c) for c in ["can1", "vcan0"])] == [1, 0]


@pytest.mark.parametrize("suffix", [".blf", ".asc", ".trc", ".csv", ".mf4", ".log"])
def test_a_log_of_many_channels_converts_to_every_format(tmp_path: Path, suffix: str, sil) -> None:  # noqa: ANN001
    source = tmp_path / "mixed.log"
    source.write_text(MIXED)
    target = tmp_path / f"out{suffix}"
    done = sil("log", "convert", str(source), str(target), "--start", "2026-12-01T10:00:00Z")
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    back = tmp_path / "back.log"
    assert sil("log", "convert", str(target), str(back)).returncode == 0
    frames = [line.split()[2] for line in back.read_text().splitlines()]
    assert frames == [line.split()[2] for line in MIXED.splitlines()]  # every frame, in order


@pytest.mark.parametrize("suffix", [".blf", ".asc"])
def test_python_cans_own_logconvert_takes_a_capture_of_our_bus(tmp_path: Path, suffix) -> None:  # noqa: ANN001
    capture = tmp_path / "capture.log"  # can.logger on the loopback bus: the group's channel
    lines = [x.replace("udp-8acf5c733522", "239.255.1.2") for x in MIXED.splitlines()]
    capture.write_text("".join(x + "\n" for x in lines if "udp-0123" not in x))
    out = tmp_path / f"capture{suffix}"
    done = subprocess.run([sys.executable, "-m", "can.logconvert", str(capture), str(out)],
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert len(list(can.LogReader(str(out)))) == 4


@pytest.mark.parametrize(
    "summary",
    ['{"status": "completed"}', '{"status": "running"}', "[]", '{"tick0_utc": 5}', "not json"],
)
def test_a_run_folder_without_tick_0_falls_back_to_its_start(tmp_path: Path, summary) -> None:  # noqa: ANN001
    (tmp_path / "can.log").write_text(MIXED.replace("udp-8acf5c733522", "vcan0"))
    (tmp_path / "summary.json").write_text(summary)  # (a run of before, or still under way)
    (tmp_path / "run.json").write_text("{}")
    start, origin = mdf.log_start(tmp_path / "can.log")
    assert origin == "the run's start (run.json)"
    assert start == (tmp_path / "run.json").stat().st_mtime_ns / 1e9


@pytest.mark.parametrize("ms", [0, 7, 85, 999])
def test_an_asc_starts_at_its_millisecond(tmp_path: Path, sil, ms: int) -> None:  # noqa: ANN001
    """The ASC header's time in three-digit milliseconds (python-can alone writes 85 ms as
    ".85", read back as 850 ms by its reader and by ours)."""
    source = tmp_path / "run.log"
    source.write_text("(0.000000) vcan0 100#01\n(0.010000) vcan0 100#02\n")
    start = f"2026-12-01T10:00:00.{ms:03d}Z"
    done = sil("log", "convert", str(source), str(tmp_path / "x.asc"), "--start", start)
    assert done.returncode == 0, done.stderr
    assert _trigger_block_s(tmp_path / "x.asc") == mdf.parse_start(start)
    first = next(iter(can.ASCReader(str(tmp_path / "x.asc"), relative_timestamp=False)))
    assert first.timestamp == pytest.approx(mdf.parse_start(start), abs=1e-6)


def _trigger_block_s(asc: Path) -> float:
    line = next(x for x in asc.read_text().splitlines() if x.startswith("Begin Triggerblock"))
    stamp = line.removeprefix("Begin Triggerblock ").strip()
    return datetime.strptime(stamp, "%a %b %d %H:%M:%S.%f %Y").replace(tzinfo=UTC).timestamp()


@pytest.mark.slow
def test_every_log_of_a_run_over_the_bus_starts_at_its_tick_0(tmp_path: Path, sil) -> None:  # noqa: ANN001
    out = tmp_path / "run"
    done = sil("run", "thesis-5.2-mrac-fast", "--out", str(out), "--no-plots", "--log-format",
               "asc", "--log-format", "blf", "--log-format", "mf4", timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mode"] == "lockstep" and summary["bus"].startswith("udp:")
    tick0 = mdf.parse_start(summary[mdf.TICK0_FIELD])
    assert (out / "run.json").stat().st_mtime < tick0 < (out / "summary.json").stat().st_mtime
    first_log_s = float((out / "can.log").read_text().split(")", 1)[0].lstrip("("))
    assert first_log_s < 1.0  # the run's own log counts simulated time from tick 0

    m = asammdf.MDF(out / "can.mf4")
    mf4_s = m.header.start_time.timestamp()
    m.close()
    blf = list(can.BLFReader(str(out / "can.blf")))
    assert len(blf) == len((out / "can.log").read_text().splitlines())
    converted = tmp_path / "converted.mf4"
    said = sil("log", "convert", str(out / "can.log"), str(converted))
    assert said.returncode == 0 and "the run's tick 0" in said.stderr + said.stdout
    c = asammdf.MDF(converted)
    converted_s = c.header.start_time.timestamp()
    c.close()
    starts = {
        "mf4": mf4_s,
        "blf": blf[0].timestamp - first_log_s,
        "asc": _trigger_block_s(out / "can.asc"),
        "sil log convert": converted_s,
    }
    assert all(abs(s - tick0) < 0.001 for s in starts.values()), (tick0, starts)
