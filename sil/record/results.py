"""A run's results folder (``sil run --out``): the names a run writes, its summary's status, and
how results are written.

A run owns only the names in :data:`RUN_FILES`: before it starts, those left by an earlier run
in the folder are removed (a user's own files stay), and ``summary.json`` says at once that the
run is ``running``. It is replaced, atomically, by the final summary (``completed``,
``aborted`` or ``touched``), or by a ``failed`` one naming the reason when the run fails before
it began or while it ended. A run killed outright leaves ``running``. ``status`` is always the
first key.

Results written at once (the summary, the run's record, plots, the log's other formats, `sil
compare`'s and `sil replay --into-ecu`'s files) are written under a temporary name in the folder
and renamed over the final one (:func:`write_atomically`, :func:`atomic`): a reader sees the old
file or the new one, never half a file, and a full disk leaves no empty file behind. A write that
fails raises :class:`WriteError`, which names the file.
"""

from __future__ import annotations

import errno
import json
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from protocol import strict_json

SUMMARY = "summary.json"
COMPLETED = "completed"
# sil.analysis.plots.plot_run: every plot a run may write (start.png only for a run from rest)
PLOTS = ("speed.png", "egt.png", "estimates.png", "gains.png", "start.png")
HANDSHAKE = (  # the node processes' handshake and stats files (sil.run.runner)
    ".plant-ready",
    ".ecu-ready",
    ".plant-start",
    ".plant-stats.json",
    ".ecu-stats.json",
)
REPLAY_FILES = ("report.json", "into_ecu.png")  # `sil replay --into-ecu --out`
RESULTS = (
    SUMMARY,
    "can.log",
    "can.asc",
    "can.blf",
    "can.mf4",
    "trace.csv",
    "scenario.toml",
    *("run.json", "commissioning.json"),  # what shaped the run (sil.run.run_record)
    "plant.log",
    "ecu.log",
    *PLOTS,
    "compare.png",  # `sil compare`'s plot goes into the second run's folder by default
    *REPLAY_FILES,  # a replay of the run's log into the ECU, written into its folder
)
TEMP_PREFIX = ".tmp."  # a result being written: renamed over its name once complete
RUN_FILES = (*RESULTS, *HANDSHAKE, *(f"{TEMP_PREFIX}{name}" for name in RESULTS))


class WriteError(OSError):
    """A result that could not be written (a full disk, no permission); the message names the
    file: ``PATH: cannot write: No space left on device``."""

    def __init__(self, path: Path | str, error: OSError) -> None:
        super().__init__(error.errno, error.strerror or str(error), str(path))
        self.path = Path(path)

    def __str__(self) -> str:
        return f"{self.filename}: cannot write: {self.strerror}"

    @classmethod
    def of(cls, path: Path | str, error: OSError) -> WriteError:
        return error if isinstance(error, WriteError) else cls(path, error)


@contextmanager
def named(path: Path | str) -> Iterator[None]:
    """An OSError in the block becomes a :class:`WriteError` naming ``path``."""
    try:
        yield
    except WriteError:
        raise
    except OSError as exc:
        raise WriteError(path, exc) from None


def temp_path(path: Path) -> Path:
    """Where ``path`` is written before it is renamed over its name (same folder, same
    suffix, so that writers that go by the suffix write the right format)."""
    return path.with_name(f"{TEMP_PREFIX}{path.name}")


@contextmanager
def atomic(path: Path) -> Iterator[Path]:
    """Write ``path`` by writing the temporary path yielded: once the block ends, it replaces
    ``path``; should the block fail, it is removed and ``path`` is left as it was. An OSError
    becomes a :class:`WriteError` naming ``path``."""
    tmp = temp_path(path)
    try:
        yield tmp
        if not tmp.exists():
            raise FileNotFoundError(errno.ENOENT, "nothing was written")
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        if isinstance(exc, OSError):
            raise WriteError.of(path, exc) from None
        raise


def write_atomically(path: Path, data: str | bytes) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` atomically (:func:`atomic`)."""
    raw = data.encode("utf-8") if isinstance(data, str) else data
    with atomic(path) as tmp:
        tmp.write_bytes(raw)
    return path


def write_with(path: Path, writer: Callable[[Path], object]) -> Path:
    """``writer(tmp)`` writes the file, which then replaces ``path`` (:func:`atomic`)."""
    with atomic(path) as tmp:
        writer(tmp)
    return path


def clear(out_dir: Path) -> list[str]:
    """Remove what an earlier run left in ``out_dir`` (only :data:`RUN_FILES`); the names
    removed, in order."""
    removed = []
    for name in RUN_FILES:
        path = out_dir / name
        if path.is_file() or path.is_symlink():
            with named(path):
                path.unlink()
            removed.append(name)
    return removed


def kept(out_dir: Path) -> list[str]:
    """The results a run has in its folder (not its temporary or handshake files)."""
    return [name for name in RESULTS if (out_dir / name).is_file()]


def status_first(summary: dict) -> dict:
    """The summary with ``status`` as its first key."""
    return {"status": summary["status"], **summary}


def write_summary(out_dir: Path, summary: dict) -> Path:
    """Write ``summary.json`` (status first) atomically: a reader sees the old or the new one."""
    text = strict_json.dumps(status_first(summary), indent=2, default=float) + "\n"
    return write_atomically(out_dir / SUMMARY, text)


def write_summary_in_place(out_dir: Path, summary: dict) -> Path:
    """The last resort when :func:`write_summary` fails (a full disk): the summary, compact,
    over the one in the folder, in the space it has (not atomic). WriteError if that fails too."""
    path = out_dir / SUMMARY
    raw = (strict_json.dumps(status_first(summary), default=float) + "\n").encode("utf-8")
    with named(path):
        with path.open("r+b") as f:
            f.write(raw)
            f.truncate()
    return path


def mark(out_dir: Path, status: str, scenario: str, reason: str | None = None) -> Path:
    """A summary with only the status (``running``, ``failed``), the reason and the scenario."""
    return write_summary(out_dir, {"status": status, "abort_reason": reason, "scenario": scenario})


class IncompleteRun(ValueError):
    """A folder that does not hold a completed run; the message names the folder and why."""


def load_summary(out_dir: Path) -> dict:
    """The run's summary; :class:`IncompleteRun` when it is missing or unreadable."""
    if not out_dir.is_dir():
        raise IncompleteRun(f"{out_dir}: no such folder")
    path = out_dir / SUMMARY
    if not path.is_file():
        raise IncompleteRun(f"{out_dir}: no {SUMMARY} (is this the output folder of a run?)")
    try:
        summary = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise IncompleteRun(f"{path}: not valid JSON: {exc}") from None
    if not isinstance(summary, dict) or not isinstance(summary.get("status"), str):
        raise IncompleteRun(f"{path}: no 'status' field: not a run's summary")
    return summary


def incomplete_reason(summary: dict) -> str | None:
    """Why a run's results are not those of a completed run (None if they are)."""
    status = summary["status"]
    if status == COMPLETED:
        return None
    if status == "running":
        return "status running: the run is still going or was killed before it ended"
    reason = summary.get("abort_reason")
    return f"status {status}" + (f": {reason}" if reason else "")
