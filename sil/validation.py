"""Checks of user input, shared by scenario files, campaign files and command-line options.

Every refusal is an `InputError` whose message reads ``SOURCE: FIELD: what was expected``, where
SOURCE is a file or ``sil COMMAND`` and FIELD a scenario field or an option. The CLI turns an
`InputError` into exit code 2 and that one line on stderr.
"""

from __future__ import annotations

import argparse
import math
import os
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any

PLANT_RATE_HZ = 1000  # the plant's RK4 step is 1 ms (plant.interface.SUBSTEP_S)


class InputError(ValueError):
    """An input that cannot be used; the message names the source and the field."""

    @classmethod
    def at(cls, source: str, field: str, message: str) -> InputError:
        return cls(one_line(f"{source}: {field}: {message}" if field else f"{source}: {message}"))


def one_line(text: str) -> str:
    """``text`` as one line: what would break it (a newline or any other line boundary a name
    or value may carry) written as its escape."""
    return "".join(
        c if c.isprintable() or c == " " else c.encode("unicode_escape").decode() for c in text
    )


def number(
    source: str,
    field: str,
    value: Any,
    *,
    lo: float | None = None,
    hi: float | None = None,
    positive: bool = False,
) -> float:
    """A finite number (not a bool), optionally positive and within ``lo..hi``."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError.at(source, field, f"expected a number, got {value!r}")
    if not math.isfinite(value):
        raise InputError.at(source, field, f"expected a finite number, got {value!r}")
    if positive and value <= 0:
        raise InputError.at(source, field, f"expected a positive number, got {value!r}")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise InputError.at(source, field, f"expected {within(lo, hi)}, got {value!r}")
    return float(value)


def within(lo: float | None, hi: float | None, what: str = "a number") -> str:
    """``what`` with its bounds in words: "a number in 0..5", "a number >= 0" (no upper
    limit), "a number <= 5" (no lower one); a missing bound is left out, never written."""
    if lo is not None and hi is not None:
        return f"{what} in {lo:g}..{hi:g}"
    if lo is not None:
        return f"{what} >= {lo:g}"
    if hi is not None:
        return f"{what} <= {hi:g}"
    return what


def option(
    *,
    integer: bool = False,
    lo: float | None = None,
    hi: float | None = None,
    positive: bool = False,
    ecu_rate_hz: bool = False,
) -> Callable[[str], Any]:
    """An argparse ``type`` checking an option's value as :func:`number` (or :func:`ecu_rate`)
    does; argparse then names the option and exits with code 2."""

    def parse(text: str) -> Any:
        try:
            value: float = int(text) if integer else float(text)
        except ValueError:
            kind = "an integer" if integer else "a number"
            raise argparse.ArgumentTypeError(f"expected {kind}, got {text!r}") from None
        try:
            if ecu_rate_hz:
                ecu_rate("", "", value)
            else:
                number("", "", value, lo=lo, hi=hi, positive=positive)
        except InputError as exc:
            raise argparse.ArgumentTypeError(str(exc).lstrip(": ")) from None
        return value

    return parse


def ecu_rate(source: str, field: str, value: Any, *, lo: float = 50, hi: float = 1000) -> float:
    """An ECU rate in ``lo..hi`` Hz whose period is a whole number of plant steps (1 ms)."""
    rate = number(source, field, value, lo=lo, hi=hi)
    steps = PLANT_RATE_HZ / rate
    if abs(steps - round(steps)) > 1e-9:
        raise InputError.at(
            source,
            field,
            f"{rate:g} Hz does not divide the plant's {PLANT_RATE_HZ} Hz "
            f"(use e.g. 50, 100, 125, 200, 250, 500 or 1000)",
        )
    return rate


def output_folder(source: str, field: str, path: Path) -> Path:
    """A folder that exists and is writable, or that can be made (its nearest existing parent is
    a writable folder); nothing is created here."""
    if path.exists():
        if not path.is_dir():
            raise InputError.at(source, field, f"{path} exists and is not a folder")
        if not os.access(path, os.W_OK | os.X_OK):
            raise InputError.at(source, field, f"{path} is not writable")
        return path
    parent = path.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise InputError.at(source, field, f"cannot make {path}: {parent} is not a writable folder")
    return path


def output_file(source: str, field: str, path: Path) -> Path:
    """A file that can be written: not a folder, in a folder that exists and is writable, and
    writable itself when it exists; nothing is created here."""
    if path.is_dir():
        raise InputError.at(source, field, f"{path} is a folder")
    folder = path.absolute().parent
    if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
        raise InputError.at(
            source, field, f"cannot write {path}: {folder} is not a writable folder"
        )
    if path.exists() and not os.access(path, os.W_OK):
        raise InputError.at(source, field, f"cannot write {path}: it is not writable")
    return path


def path_option(text: str) -> Path:
    """An argparse ``type`` for a path: an empty one is refused (``Path("")`` is the current
    folder, which a user who left a variable empty did not mean)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path (. is the current folder)")
    return Path(text)


def file_option(text: str) -> Path:
    """An argparse ``type`` for a file to write (:func:`output_file`)."""
    try:
        return output_file("", "", path_option(text))
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc).lstrip(": ")) from None


def folder_option(text: str) -> Path:
    """An argparse ``type`` for an output folder (:func:`output_folder`)."""
    try:
        return output_folder("", "", path_option(text))
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc).lstrip(": ")) from None


def bus_option(text: str) -> str:
    """An argparse ``type`` for ``--bus``: an empty spec is refused (it would otherwise stand for
    the default bus, which a user who left a variable empty did not mean)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty bus spec")
    return text


# the kernel's trees: their files are interfaces (a process's environment, memory maps), not input
KERNEL_TREES = (Path("/proc"), Path("/sys"))


def input_file(path: Path, where: str | None = None) -> Path:
    """A file to read: refused when it lies in the kernel's trees (/proc, /sys) or exists and is
    not a regular file (a device such as /dev/zero, a pipe, a folder), before anything reads it,
    so that no message ever quotes such a file's content. A missing file passes (its reader
    says so). The refusal reads ``WHERE: why``, WHERE the path unless given."""
    where = str(path) if where is None else where
    try:
        real = path.resolve()
        mode = path.stat().st_mode
    except FileNotFoundError:
        return path
    except (OSError, RuntimeError) as exc:
        raise InputError(one_line(f"{where}: cannot read it: {exc}")) from None
    if stat.S_ISDIR(mode):
        raise InputError(one_line(f"{where}: a folder, not a file"))
    if not stat.S_ISREG(mode):
        raise InputError(one_line(f"{where}: not a regular file (a device or a pipe)"))
    tree = next((t for t in KERNEL_TREES if real == t or t in real.parents), None)
    if tree is not None:
        raise InputError(one_line(f"{where}: a kernel file under {tree}, not an input"))
    return path


def input_option(text: str) -> Path:
    """An argparse ``type`` for a file to read (:func:`input_file`); an empty path is refused."""
    try:
        return input_file(path_option(text))
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
