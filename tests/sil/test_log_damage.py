"""Damaged logs in every supported format, written by python-can's own writers: a last record cut
short is an error naming the file and its line or byte, after the frames before it; a frame of
one of our messages with a wrong length is reported as such, not as an unknown ID."""

import functools
import gzip
import json
import re
from pathlib import Path

import can
import pytest

from protocol.codec import Codec
from sil.record.canlog import LogReadError, detect_format, read_frames

WRITERS = {
    "candump": (can.CanutilsLogWriter, "log"),
    "asc": (can.ASCWriter, "asc"),
    "blf": (can.BLFWriter, "blf"),
    "trc": (can.TRCWriter, "trc"),
    "csv": (can.CSVWriter, "csv"),
}
FRAMES = 30


def _messages(count: int = FRAMES, short_at: int | None = None) -> list[can.Message]:
    """Our PlantSensors and EcuActuator frames, packed by the codec; ``short_at``: that frame
    (a PlantSensors one, if even) cut to 5 bytes."""
    codec = Codec()
    out = []
    for k in range(count):
        name = "PlantSensors" if k % 2 == 0 else "EcuActuator"
        values = [k, 100_000 + k, 1000.0] if k % 2 == 0 else [1, 2, k, 40.0, 5.0]
        m = codec[name]
        m.pack(values)
        data = bytes(m.data)[:5] if k == short_at else bytes(m.data)
        out.append(
            can.Message(
                timestamp=1.0 + k * 0.01,
                arbitration_id=m.frame_id,
                data=data,
                channel=0,
                is_extended_id=False,
            )
        )
    return out


def _write(path: Path, fmt: str, messages: list[can.Message]) -> Path:
    writer_class, _ = WRITERS[fmt]
    writer = writer_class(str(path))
    for m in messages:
        writer.on_message_received(m)
    writer.stop()
    return path


def _read_until_error(path: Path) -> tuple[list[can.Message], LogReadError]:
    got = []
    with pytest.raises(LogReadError) as info:
        for m in read_frames(path):
            got.append(m)
    return got, info.value


def _last_record_span(data: bytes, fmt: str) -> tuple[int, int, int]:
    """The last frame's record in a text log: its first byte, the byte after its content (before
    the end of line) and its line number."""
    lines = data.splitlines(keepends=True)
    index = max(i for i, ln in enumerate(lines) if re.search(rb"(#|\bRx\b|^\d+\.\d+,0x)", ln))
    start = sum(len(ln) for ln in lines[:index])
    return start, start + len(lines[index].rstrip(b"\r\n")), index + 1


@pytest.mark.parametrize("fmt", [f for f in WRITERS if f != "blf"])
def test_a_text_log_cut_in_its_last_record_names_the_line_and_keeps_the_rest(tmp_path, fmt, sil):
    full = _write(tmp_path / f"full.{WRITERS[fmt][1]}", fmt, _messages())
    assert detect_format(full) == (fmt, False)
    assert len(list(read_frames(full))) == FRAMES  # the whole file reads without error
    data = full.read_bytes()
    start, end, line = _last_record_span(data, fmt)
    # every cut inside the record's content; for TRC (whose files from PEAK's tools may end
    # without an end of line) not within the trailing padding of a whole record
    content = data[start:end]
    cuts = range(start + 1, start + len(content.rstrip()) if fmt == "trc" else end + 1)
    cut_path = tmp_path / f"cut.{WRITERS[fmt][1]}"
    for cut in cuts:
        cut_path.write_bytes(data[:cut])
        got, error = _read_until_error(cut_path)
        assert error.path == cut_path and error.position == f"line {line}", (cut, str(error))
        assert len(got) == error.frames_read == FRAMES - 1, cut
        assert got[-1].data == _messages()[-2].data
        assert str(error).startswith(f"{cut_path}: line {line}: ")
    assert len(cuts) >= 20
    _commands_report(sil, cut_path, f"{cut_path}: line {line}: ", FRAMES - 1)


def _commands_report(sil, path: Path, where: str, frames: int) -> None:
    """`sil replay --dry-run` reports what it read, then the error (exit 1); `sil identify`
    refuses the file (exit 2); both name the file and the position."""
    dry = sil("replay", "--dry-run", "--json", str(path))
    assert dry.returncode == 1 and dry.stderr.startswith(f"sil replay: {where}")
    report = json.loads(dry.stdout)
    assert report["frames"] == frames and report["error"].startswith(where)
    ident = sil("identify", str(path))
    assert ident.returncode == 2 and ident.stderr.startswith(f"sil identify: {where}")


def test_an_asc_log_without_its_end_of_trigger_block_is_truncated(tmp_path):
    data = _write(tmp_path / "full.asc", "asc", _messages()).read_bytes()
    assert data.rstrip().endswith(b"End TriggerBlock")
    cut = tmp_path / "cut.asc"
    cut.write_bytes(data[: data.rindex(b"End TriggerBlock")])  # cut at a line boundary
    got, error = _read_until_error(cut)
    assert len(got) == FRAMES and "truncated ASC: it ends without 'End TriggerBlock'" in str(error)


def test_a_blf_log_cut_anywhere_names_the_byte(tmp_path, sil):
    data = _write(tmp_path / "full.blf", "blf", _messages()).read_bytes()
    cut = tmp_path / "cut.blf"
    for size in range(len(data) - 1, 143, -7):  # every 7th size down to the file header
        cut.write_bytes(data[:size])
        _, error = _read_until_error(cut)
        assert re.fullmatch(r"byte \d+", error.position), str(error)
        assert str(error).startswith(f"{cut}: byte "), str(error)
    cut.write_bytes(data[:-1])
    _, error = _read_until_error(cut)
    assert str(error).startswith(f"{cut}: byte {len(data) - 1}: truncated BLF: the header says")
    # (its container was whole)
    _commands_report(sil, cut, f"{cut}: byte {len(data) - 1}: ", FRAMES)


@pytest.mark.parametrize("fmt", list(WRITERS))
def test_a_gzipped_log_cut_short_is_an_error_after_what_it_held(tmp_path, fmt):
    full = _write(tmp_path / f"full.{WRITERS[fmt][1]}", fmt, _messages(300))
    packed = gzip.compress(full.read_bytes())
    cut = tmp_path / f"cut.{WRITERS[fmt][1]}.gz"
    cut.write_bytes(packed)
    assert detect_format(cut) == (fmt, True) and len(list(read_frames(cut))) == 300
    for size in (len(packed) - 1, len(packed) - 9, len(packed) * 2 // 3):
        cut.write_bytes(packed[:size])
        assert detect_format(cut) == (fmt, True)  # the format is still recognised
        got, error = _read_until_error(cut)
        assert "truncated gzip data" in str(error) and str(error).startswith(f"{cut}: ")
        assert error.frames_read == len(got)
    assert len(got) > 100 or fmt == "blf"  # (BLF: its one compressed container is cut)


@pytest.fixture
def sil(sil):
    """tests/conftest.py's ``sil`` with 120 s for a command."""
    return functools.partial(sil, timeout=120)


WRONG = "wrong length for PlantSensors (0x100): got 5, expected 8"


@pytest.mark.parametrize("fmt", list(WRITERS))
def test_a_frame_of_ours_with_a_wrong_length_is_reported_as_such(tmp_path, fmt, sil):
    path = _write(tmp_path / f"short.{WRITERS[fmt][1]}", fmt, _messages(short_at=10))
    # python-can reads the frame back as written: 5 bytes of PlantSensors' ID
    frame = [m for m in read_frames(path)][10]
    db = Codec().database
    assert frame.arbitration_id == db.get_message_by_name("PlantSensors").frame_id
    assert len(frame.data) == 5 and db.get_message_by_name("PlantSensors").length == 8
    position = "frame 11" if fmt == "blf" else None
    result = sil("replay", "--dry-run", "--json", str(path))
    assert result.returncode == 1
    report = json.loads(result.stdout)
    assert report["wrong_length"] == {WRONG: 1}
    assert report["unknown_ids"] == {} and "error" not in report
    assert report["decoded"] == {"PlantSensors": 14, "EcuActuator": 15}
    (line,) = result.stderr.splitlines()
    where = re.fullmatch(
        rf"sil replay: {re.escape(str(path))}: (.+): {re.escape(WRONG)} \(1 frames\)", line
    )
    assert where is not None, line
    if position is not None:
        assert where.group(1) == position
    else:  # the frame's own line
        text = path.read_text(encoding="latin-1").splitlines()
        number = int(where.group(1).removeprefix("line "))
        assert re.search(r"(^|[^0-9A-Fa-f])(0x)?0*100\b", text[number - 1]), text[number - 1]
    text_report = sil("replay", "--dry-run", str(path))
    assert f"(wrong length for PlantSensors (0x100): got 5, expected 8) {frame.data.hex()}" in (
        text_report.stdout
    )
    # the ECU replay and identification refuse it, naming the same place
    into = sil("replay", "--into-ecu", "--scenario", "thesis-5.4-staircase", str(path))
    assert into.returncode == 1
    assert into.stderr.startswith(f"sil replay: {path}: {where.group(1)}: {WRONG}")
    ident = sil("identify", str(path))
    assert ident.returncode == 2
    assert ident.stderr.startswith(f"sil identify: {path}: {where.group(1)}: {WRONG}")


def test_a_trc_record_with_a_column_missing_mid_file_is_an_error_other_types_are_skipped(tmp_path):
    """python-can drops a TRC record it cannot parse (a warning in its log); here it is an
    error at its line, after the frames before it. A status record (a type python-can skips)
    holds no frame and is no error."""
    lines = _write(tmp_path / "full.trc", "trc", _messages(6)).read_text().splitlines(True)
    first = next(i for i, ln in enumerate(lines) if not ln.startswith(";"))
    status = "      9      1000.000 ST  1     Rx    00 00 00 04\n"
    skipped = tmp_path / "status.trc"
    skipped.write_text("".join([*lines[: first + 2], status, *lines[first + 2 :]]))
    assert len(list(read_frames(skipped))) == 6
    cut = tmp_path / "cut.trc"
    cut.write_text(
        "".join([*lines[: first + 2], lines[first + 2][:24] + "\n", *lines[first + 3 :]])
    )
    got, error = _read_until_error(cut)
    assert len(got) == error.frames_read == 2
    assert error.position == f"line {first + 3}", str(error)
    assert "not a whole TRC record (a column missing)" in error.reason
