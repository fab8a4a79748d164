"""Log reading and replay: foreign logs in dry run, damaged files, real-time playback."""

import functools
import gzip
import json
from pathlib import Path

import can
import pytest

from protocol.bus import open_bus
from protocol.codec import Codec
from sil.record import replay
from sil.record.canlog import CandumpWriter, LogReadError, detect_format, read_frames

FOREIGN = Path(__file__).resolve().parents[3] / "shared" / "data" / "foreign-logs"
FOREIGN_LOGS = sorted(p for p in FOREIGN.glob("*") if p.suffix != ".md")


@pytest.fixture
def sil(sil):
    """tests/conftest.py's ``sil`` with 120 s for a command."""
    return functools.partial(sil, timeout=120)


def _our_log(path: Path, ticks: int = 50) -> Path:
    codec = Codec()
    writer = CandumpWriter(path)
    for k in range(ticks):
        for name, values in (
            ("PlantSensors", [k, 100_000 + k, 1000.0]),
            ("EcuActuator", [1, 2, k, 40.0, 5.0]),
        ):
            m = codec[name]
            m.pack(values)
            writer.write(k * 0.001, m.frame_id, m.data)
    writer.close()
    return path


def test_foreign_logs_are_there():
    assert len(FOREIGN_LOGS) >= 10, f"expected the foreign logs in {FOREIGN}"


@pytest.mark.parametrize("path", FOREIGN_LOGS, ids=lambda p: p.name)
def test_foreign_logs_dry_run_without_error(path, sil):
    result = sil("replay", "--dry-run", "--json", str(path))
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["frames"] > 0 and report["decoded"] == {}  # none carries our messages
    counted = sum(report["unknown_ids"].values()) + sum(report["skipped"].values())
    assert counted == report["frames"]


def test_format_is_detected_from_content_not_name(tmp_path):
    disguised = tmp_path / "capture.txt"
    disguised.write_bytes((FOREIGN / "test_CanMessage.blf").read_bytes())
    assert detect_format(disguised) == ("blf", False)
    asc = tmp_path / "capture.log"
    asc.write_bytes(gzip.decompress((FOREIGN / "test_CanMessage.asc.gz").read_bytes()))
    assert detect_format(asc) == ("asc", False)
    assert detect_format(FOREIGN / "test_CanMessage.asc.gz") == ("asc", True)
    ours = _our_log(tmp_path / "ours.asc")  # candump content behind an .asc name
    assert detect_format(ours) == ("candump", False)
    assert sum(1 for _ in read_frames(ours)) == 100


def test_truncated_and_corrupt_files_name_the_position(tmp_path, sil):
    blf = (FOREIGN / "issue_1905.blf").read_bytes()
    (tmp_path / "short.blf").write_bytes(blf[:300])
    with pytest.raises(LogReadError, match=r"short.blf: byte 300: truncated BLF"):
        list(read_frames(tmp_path / "short.blf"))
    log = _our_log(tmp_path / "cut.log", ticks=5).read_text()
    (tmp_path / "cut.log").write_text(log[: len(log) - 7])  # cut inside the last line
    with pytest.raises(
        LogReadError, match=r"cut.log: line 10: last line cut short.*after 9 frames"
    ):
        list(read_frames(tmp_path / "cut.log"))
    (tmp_path / "noise.log").write_text("(0.1) vcan0 100#00\nsomething else\n")
    result = sil("replay", "--dry-run", str(tmp_path / "noise.log"))
    assert result.returncode == 1
    assert "noise.log: line 2: not a candump -L line" in result.stderr
    assert "frames: 1" in result.stdout  # what was read is reported first


def test_bad_crc_repeats_and_gaps_are_counted_not_fatal(tmp_path, sil):
    path = _our_log(tmp_path / "damaged.log", ticks=30)
    lines = path.read_text().splitlines()
    flipped = lines[10][:-1] + ("0" if lines[10][-1] != "0" else "1")
    lines[10] = flipped  # bad CRC
    lines.insert(20, lines[19])  # a repeated frame
    del lines[40]  # a lost frame
    path.write_text("\n".join(lines) + "\n")
    report = json.loads(sil("replay", "--dry-run", "--json", str(path)).stdout)
    problems = report["e2e_problems"]
    assert problems["PlantSensors"]["WRONGCRC"] == 1
    assert sum(problems["EcuActuator"].values()) >= 1 or sum(problems["PlantSensors"].values()) > 1


def test_playback_timing_and_filter(tmp_path):
    path = _our_log(tmp_path / "play.log", ticks=200)  # 0.2 s at 1 kHz
    with open_bus("virtual:replay_test") as tx, open_bus("virtual:replay_test") as rx:
        report = replay.play(path, tx, keep=replay.id_filter("0x100"))
        got = []
        while (m := rx.recv(0.1)) is not None:
            got.append(m)
    assert report.sent == 200 and len(got) == 200
    assert all(m.arbitration_id == 0x100 for m in got)
    assert report.duration_s >= 0.199  # never early; timing figures: `sil bench replay`
    assert min(report.errors_s) >= 0


def test_schedule_speed_and_gap_skipping():
    frames = [can.Message(timestamp=t) for t in (10.0, 10.5, 20.5, 21.0)]
    times = [t for t, _ in replay.schedule(frames, speed=2.0, skip_gaps=1.0)]
    assert times == [0.0, 0.25, 0.75, 1.0]


def test_id_filter_errors():
    assert replay.id_filter("0x100-0x1FF,0x300")(0x150)
    assert not replay.id_filter("0x100-0x1FF,0x300")(0x200)
    with pytest.raises(ValueError, match="'zz'"):
        replay.id_filter("zz")
