"""A results folder given with ``--out`` (`sil run`, `sil demo`, `sil replay --into-ecu`, `sil
compare`): refused before anything is touched when it cannot be one, made, and locked while a
command writes it.

- :func:`out_path` takes the option's text: an empty path is refused (it would make the current
  folder the results folder by accident; ``--out .`` says so on purpose).
- :func:`check` refuses a path that cannot be a results folder (a file, a folder that is not
  writable or cannot be made, one on a kernel file system such as /proc or /sys), touching
  nothing.
- :class:`FolderLock` makes the folder and holds ``.lock`` in it (``flock``) while a command
  writes it: a second command into the folder is refused at once, naming the process that holds
  it. The lock ends with the command, or with its process, whatever kills it; the file is
  removed while still locked, so that a command that opened it meanwhile takes it again from a
  new file.

Every refusal is a :class:`FolderError` (exit code 2) whose message names the option, the path
and why.
"""

from __future__ import annotations

import errno
import fcntl
import os
from pathlib import Path

LOCK = ".lock"
# kernel file systems: paths there are interfaces to the kernel, not places for files
KERNEL_FS = frozenset(
    "proc sysfs cgroup cgroup2 debugfs tracefs securityfs configfs pstore bpf efivarfs fusectl "
    "devtmpfs devpts mqueue binfmt_misc selinuxfs autofs".split()
)


class FolderError(ValueError):
    """A results folder that cannot be used; the message names the option and the path."""


class FolderBusy(FolderError):
    """The folder is being written by another command (its PID in the message)."""


def out_path(option: str, text: str | Path | None) -> Path | None:
    """The folder ``--out`` names (None when not given); an empty path is refused."""
    if text is None:
        return None
    if str(text) == "":
        raise FolderError(f"{option}: an empty path (give a folder; --out . is this one)")
    return Path(text)


def check(option: str, path: Path) -> Path:
    """``path`` if it is, or can be made, a folder to write results into; else FolderError
    naming ``option`` and why. Nothing is created."""
    where = f"{option} {path}"
    if str(path) == "":
        raise FolderError(f"{option}: an empty path (give a folder; --out . is this one)")
    fs = _kernel_fs(path)
    if fs is not None:
        raise FolderError(f"{where}: on the kernel's {fs} file system, not a place for files")
    if path.exists():
        if not path.is_dir():
            raise FolderError(f"{where}: exists and is not a folder")
        if not os.access(path, os.W_OK | os.X_OK):
            raise FolderError(f"{where}: the folder is not writable")
        return path
    parent = _existing_parent(path)
    if not parent.is_dir():
        raise FolderError(f"{where}: cannot make it: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise FolderError(f"{where}: cannot make it: {parent} is not writable")
    return path


def _existing_parent(path: Path) -> Path:
    parent = path.absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    return parent


def _kernel_fs(path: Path) -> str | None:
    """The kernel file system ``path`` (or the nearest folder of it that exists) is on, or
    None (any other file system, or no /proc/self/mountinfo to tell)."""
    target = path if path.exists() else _existing_parent(path)
    try:
        real = str(target.resolve())
        lines = Path("/proc/self/mountinfo").read_text().splitlines()
    except (OSError, RuntimeError):
        return None
    best, best_fs = "", None
    for line in lines:
        fields = line.split()
        try:
            mount_point = fields[4].encode().decode("unicode_escape")
            fs_type = fields[fields.index("-") + 1]
        except (IndexError, ValueError, UnicodeDecodeError):
            continue
        inside = real == mount_point or real.startswith(mount_point.rstrip("/") + "/")
        if inside and len(mount_point) >= len(best):
            best, best_fs = mount_point, fs_type
    return best_fs if best_fs in KERNEL_FS else None


class FolderLock:
    """Make ``path`` (as :func:`check` allowed) and lock it for this process; ``release`` (or
    leaving the ``with`` block) ends the lock. ``option`` names the folder in refusals."""

    def __init__(self, path: Path, option: str = "--out") -> None:
        self.path = path
        self.option = option
        self._fd: int | None = None
        made = self._make()
        try:
            self._fd = self._lock()
        except BaseException:
            _remove_made(made)
            raise

    def _make(self) -> list[Path]:
        """Make the folder and its missing parents; those it made (innermost last)."""
        missing = []
        folder = self.path.absolute()
        while not folder.exists() and folder != folder.parent:
            missing.append(folder)
            folder = folder.parent
        made: list[Path] = []
        try:
            for folder in reversed(missing):
                folder.mkdir()
                made.append(folder)
        except FileExistsError:  # made meanwhile by another command: it may be a folder
            if not self.path.is_dir():
                _remove_made(made)
                raise FolderError(
                    f"{self.option} {self.path}: exists and is not a folder"
                ) from None
        except OSError as exc:
            _remove_made(made)
            raise FolderError(
                f"{self.option} {self.path}: cannot make it: {exc.strerror or exc}"
            ) from None
        return made

    def _lock(self) -> int:
        lock = self.path / LOCK
        while True:
            try:
                fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o644)
            except OSError as exc:
                raise FolderError(
                    f"{self.option} {self.path}: cannot write in the folder: {exc.strerror or exc}"
                ) from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                holder = _holder(fd)
                os.close(fd)
                if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise FolderError(
                        f"{self.option} {self.path}: cannot lock the folder: {exc.strerror}"
                    ) from None
                raise FolderBusy(
                    f"{self.option} {self.path}: the folder is in use by another run "
                    f"({holder}); wait for it to end or choose another folder"
                ) from None
            if _same_file(fd, lock):
                _write_pid(fd)
                return fd
            os.close(fd)  # released and removed meanwhile: lock the new file

    def release(self) -> None:
        if self._fd is None:
            return
        try:  # removed while locked: a command that opened it meanwhile finds it gone
            (self.path / LOCK).unlink(missing_ok=True)
        except OSError:
            pass
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> FolderLock:
        return self

    def __exit__(self, *_: object) -> None:
        self.release()


def _remove_made(made: list[Path]) -> None:
    """Remove the folders a refused command made (innermost first), if still empty."""
    for folder in reversed(made):
        try:
            folder.rmdir()
        except OSError:
            return


def _holder(fd: int) -> str:
    """Who holds the lock, as the lock file says: ``pid N`` (or ``pid unknown``)."""
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        text = ""
    return f"pid {text}" if text.isdigit() else "pid unknown"


def _write_pid(fd: int) -> None:
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
    except OSError:  # (a full disk: the lock holds without it)
        pass


def _same_file(fd: int, path: Path) -> bool:
    try:
        return os.path.samestat(os.fstat(fd), os.stat(path, follow_symlinks=False))
    except FileNotFoundError:
        return False
