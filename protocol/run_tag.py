"""Run tags: several runs on one bus, each with IDs of its own.

A run claims a small tag per bus. Tag 0 is the primary run: its frames carry the DBC IDs as they
are (standard 11-bit IDs), so a run alone on its bus sends what it always sent. A run of tag
``t > 0`` sends each frame with the 29-bit extended ID ``(t << 11) | dbc_id``, which no other
run uses. :func:`wire_id` and :func:`split_id` map between the two.

Tags are claimed with ``flock`` on one file per bus and tag in a per-user runtime folder: the
claim is the open file, so it ends when the run releases it (which removes the file) or its
process dies (which leaves the file, free, to the next run).
"""

from __future__ import annotations

import fcntl
import os
import tempfile
from pathlib import Path
from urllib.parse import quote

DBC_ID_BITS = 11
DBC_ID_MASK = (1 << DBC_ID_BITS) - 1
MAX_TAG = 255  # tags 0..MAX_TAG: as many runs at once on one bus


class TagsExhausted(RuntimeError):
    """Every tag of the bus is claimed by a running run."""


def wire_id(tag: int, dbc_id: int) -> tuple[int, bool]:
    """The arbitration ID and whether it is extended, for a DBC frame ID of run ``tag``."""
    if not 0 <= dbc_id <= DBC_ID_MASK or not 0 <= tag <= MAX_TAG:
        raise ValueError(f"no wire ID for tag {tag}, DBC ID {dbc_id}")
    if tag == 0:
        return dbc_id, False
    return (tag << DBC_ID_BITS) | dbc_id, True


def split_id(arbitration_id: int, extended: bool) -> tuple[int, int] | None:
    """``(tag, dbc_id)`` of a frame on the wire; None for an extended ID no run sends."""
    if not extended:
        return 0, arbitration_id
    tag = arbitration_id >> DBC_ID_BITS
    if not 1 <= tag <= MAX_TAG:
        return None
    return tag, arbitration_id & DBC_ID_MASK


def tag_dir() -> Path:
    """The folder of the tag files: per user, in the runtime folder where there is one."""
    base = os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()
    return Path(base) / f"turbojet-sil-{os.getuid()}" / "run-tags"


def tag_file(bus: str, tag: int) -> Path:
    """The file of a tag of a bus (a bus spec string, quoted into a file name)."""
    return tag_dir() / f"{quote(bus, safe='@')}.{tag}.lock"


class TagClaim:
    """A run's tag on one bus, held until :meth:`release` (or the process ends)."""

    def __init__(self, tag: int, path: Path, fd: int) -> None:
        self.tag = tag
        self.path = path
        self._fd: int | None = fd

    def release(self) -> None:
        if self._fd is not None:
            # removed while locked: a run that opened it meanwhile finds it gone (_same_file)
            self.path.unlink(missing_ok=True)
            os.close(self._fd)  # closing the file ends the flock
            self._fd = None

    def __enter__(self) -> TagClaim:
        return self

    def __exit__(self, *_: object) -> None:
        self.release()


def claim_tag(bus: str) -> TagClaim:
    """The lowest tag of ``bus`` (a bus spec string) that no running run holds."""
    tag_dir().mkdir(parents=True, exist_ok=True, mode=0o700)
    tag = 0
    while tag <= MAX_TAG:
        path = tag_file(bus, tag)
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            tag += 1
            continue
        if _same_file(fd, path):
            return TagClaim(tag, path, fd)
        os.close(fd)  # released and removed meanwhile: the same tag again, on a new file
    raise TagsExhausted(f"bus {bus}: all {MAX_TAG + 1} run tags are in use")


def _same_file(fd: int, path: Path) -> bool:
    """The open file is still the one at ``path`` (a release removes it)."""
    try:
        return os.path.samestat(os.fstat(fd), os.stat(path))
    except FileNotFoundError:
        return False
