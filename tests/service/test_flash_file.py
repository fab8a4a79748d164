"""The file an ECU is given as its flash image (`sil ecu --flash FILE`): a missing or empty file
becomes an erased image; an image opens, also with a save cut short in one slot; any other file
is refused, named and left as it is, as are /dev/null, a folder and a pipe; an image is locked
while an ECU holds it, and a second ECU on it is refused."""

from __future__ import annotations

import os
import time

import pytest

from ecu.service.storage import (
    HEADER,
    IMAGE_SIZE,
    SLOT_SIZE,
    FlashImage,
    StorageError,
    load,
)


def _refused(path, *words: str) -> None:
    with pytest.raises(StorageError) as refused:
        FlashImage(path)
    message = str(refused.value)
    assert message.startswith(f"{path}: ") and "\n" not in message
    for word in words:
        assert word in message, message


def test_a_missing_or_empty_file_becomes_an_erased_image(tmp_path):
    empty = tmp_path / "empty.bin"
    empty.touch()
    for path in (tmp_path / "new.bin", empty):
        FlashImage(path).close()
        assert path.read_bytes() == b"\xff" * IMAGE_SIZE


def test_a_file_that_is_not_an_image_is_refused_and_left_as_it_is(tmp_path):
    image_sized = bytes(range(256)) * (IMAGE_SIZE // 256)
    notes = b"speed 70 %N\negt 900 K\n"
    cases = {
        "notes.txt": (notes, f"text of {len(notes)} bytes"),
        "long.txt": (b"x" * (IMAGE_SIZE + 100), f"text of {IMAGE_SIZE + 100} bytes"),
        "zeros.bin": (bytes(IMAGE_SIZE), f"binary data of {IMAGE_SIZE} bytes"),
        "other.bin": (image_sized, "slot 0 holds neither a stored set nor erased flash"),
        "short.bin": (b"\xff" * (IMAGE_SIZE - 1), f"a flash image has {IMAGE_SIZE} bytes"),
    }
    for name, (content, what) in cases.items():
        path = tmp_path / name
        path.write_bytes(content)
        _refused(path, what, "not a flash image", "left as it is")
        assert path.read_bytes() == content, name


def test_an_image_with_a_slot_cut_short_or_damaged_opens(tmp_path):
    """A save cut after each of its flash operations, and a bit flipped in a stored set: still
    an image of ours, opened with the last good set."""
    path = tmp_path / "flash.bin"
    with FlashImage(path) as flash:
        flash.save(b"good " * 30)
        flash.save(b"better " * 30)
        operations = flash.writer(b"next " * 300, page_size=64).operations
    start = path.read_bytes()
    for cut in range(operations):
        path.write_bytes(start)
        with FlashImage(path) as flash:
            writer = flash.writer(b"next " * 300, page_size=64)
            for _ in range(cut):
                writer.step()
        with FlashImage(path) as flash:
            assert flash.newest().payload == b"better " * 30, f"cut after {cut}"
    damaged = bytearray(start)
    damaged[SLOT_SIZE + HEADER.size] ^= 0x01
    path.write_bytes(bytes(damaged))
    with FlashImage(path) as flash:
        assert flash.newest().payload == b"good " * 30


def test_what_is_not_a_regular_file_is_refused(tmp_path):
    _refused("/dev/null", "a character device", "not a flash image file")
    _refused(tmp_path, "a folder")
    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)
    _refused(pipe, "a named pipe")


def test_an_image_is_locked_while_open(tmp_path):
    path = tmp_path / "flash.bin"
    first = FlashImage(path)
    first.save(b"held")
    _refused(path, "another ECU holds this flash image", f"pid {os.getpid()}")
    first.close()
    with FlashImage(path) as again:
        assert again.newest().payload == b"held"


@pytest.mark.slow
@pytest.mark.parametrize("impl", ["python", "c"])
def test_sil_ecu_refuses_a_file_that_is_not_an_image(impl, tmp_path, sil, udp_spec):
    notes, text = tmp_path / "notes.txt", "bench notes: pump 12 V\n"
    notes.write_text(text)
    done = sil("ecu", "--impl", impl, "--bus", udp_spec(), "--flash", str(notes), timeout=60)
    assert done.returncode == 2, done.stderr
    assert f"sil ecu: {notes}: text of {len(text)} bytes, not a flash image" in done.stderr
    assert done.stderr.count("\n") == 1 and notes.read_text() == text
    done = sil("ecu", "--impl", impl, "--bus", udp_spec(), "--flash", "/dev/null", timeout=60)
    assert done.returncode == 2
    assert "sil ecu: /dev/null: a character device, not a flash image file" in done.stderr


@pytest.mark.slow
def test_a_second_sil_ecu_on_an_image_in_use_is_refused(tmp_path, sil, sil_process, udp_spec):
    """A Python ECU holds the image: a C ECU on the same file is refused, naming the file and
    the first ECU's process, and the image is as the first ECU left it."""
    flash, ready = tmp_path / "flash.bin", tmp_path / "ready"
    first = sil_process(
        "ecu", "--bus", udp_spec(), "--flash", str(flash), "--ready-file", str(ready)
    )
    try:
        deadline = time.monotonic() + 60
        while not ready.exists() and first.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert ready.exists(), first.stderr.read() if first.poll() is not None else "not ready"
        image = flash.read_bytes()
        done = sil("ecu", "--impl", "c", "--bus", udp_spec(), "--flash", str(flash), timeout=60)
        held = f"sil ecu: {flash}: another ECU holds this flash image (pid {first.pid})"
        assert done.returncode == 2 and held in done.stderr, done.stderr
        assert flash.read_bytes() == image and load(flash) is None
    finally:
        first.terminate()
        first.communicate(timeout=30)
