"""A run folder (`sil run --out`, `sil compare`, `sil replay --into-ecu --out`): an unusable
--out is refused before anything is touched, a folder being written is locked, a run clears every
file an earlier run wrote (plots included), and results are written atomically: a full disk
leaves no empty or half file, names the file, and never passes a run that flew for one that did
not begin."""

from __future__ import annotations

import errno
import json
import os
import re
import subprocess
from pathlib import Path

import pytest

from sil import cli
from sil.record import results
from sil.run import run_folder

SCENARIO = """
duration_s = {duration}
[plant]
model = "aero"
[controller]
kind = "mrac"
preset = "sec5_3_mrac_aero"
params = {{ rate_window_s = 0.05 }}
[command]
base = 0
[[command.component]]
kind = "staircase"
levels = [90, 92]
step_s = 1
"""


def _scenario(tmp_path: Path, duration: float = 2.0) -> Path:
    path = tmp_path / f"s{duration:g}.toml"
    path.write_text(SCENARIO.format(duration=duration))
    return path


def _main(argv: list[str], capsys) -> tuple[int, str, str]:
    try:
        code = cli.main(argv)
    except SystemExit as exc:
        code = int(exc.code or 0)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _contents(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.mark.parametrize(
    ("out", "why"),
    [
        ("", "--out: an empty path (give a folder; --out . is this one)"),
        ("/proc/foo", "--out /proc/foo: on the kernel's proc file system, not a place for files"),
        ("/proc", "--out /proc: on the kernel's proc file system, not a place for files"),
        ("/sys/foo", "--out /sys/foo: on the kernel's sysfs file system, not a place for files"),
        ("/dev", "--out /dev: on the kernel's devtmpfs file system, not a place for files"),
        ("summary.json", "--out summary.json: exists and is not a folder"),
    ],
)
def test_an_unusable_out_is_refused_before_anything_is_touched(
    tmp_path, monkeypatch, capsys, out, why
):
    monkeypatch.chdir(tmp_path)
    for name in ("speed.png", "trace.csv", "summary.json"):  # an earlier run's, in this folder
        (tmp_path / name).write_text(f"earlier {name}")
    scenario = str(_scenario(tmp_path))
    before = _contents(tmp_path)
    for argv in (
        ["run", scenario, "--mode", "inproc", "--out", out],
        ["run", "no-such-scenario", "--out", out],
        ["demo", "--mode", "inproc", "--out", out],
    ):
        code, _, err = _main(argv, capsys)
        assert code == 2, err
        assert err.splitlines() == [f"sil {argv[0]}: {why}"]
        assert _contents(tmp_path) == before  # nothing deleted, nothing written


def test_a_folder_that_cannot_be_made_is_refused_and_nothing_is_left(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, _, err = _main(["run", str(_scenario(tmp_path)), "--out", str(blocker / "a" / "b")],
                         capsys)  # fmt: skip
    assert code == 2 and err.strip().endswith(f"cannot make it: {blocker} is not a folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "s2.toml"]
    # past the checks, a folder the kernel will not make is refused as such, and nothing made
    with pytest.raises(run_folder.FolderError, match="--out /sys/kernel/no-such/run: cannot make"):
        run_folder.FolderLock(Path("/sys/kernel/no-such/run"))


def test_a_folder_being_written_is_locked_naming_the_other_run(tmp_path, capsys, sil):
    out, good = tmp_path / "run", tmp_path / "good"
    scenario = str(_scenario(tmp_path))
    code, _, err = _main(["run", scenario, "--mode", "inproc", "--out", str(good), "--no-plots"],
                         capsys)  # fmt: skip
    assert code == 0, err
    with run_folder.FolderLock(out):  # as a run holds it while it writes
        (out / "summary.json").write_text('{"status": "running"}')
        before = _contents(out)
        for argv in (
            ["run", scenario, "--mode", "inproc", "--out", str(out)],
            ["compare", str(good), str(good), "--out", str(out)],
            ["replay", str(good / "can.log"), "--into-ecu", "--out", str(out)],
        ):
            code, _, err = _main(argv, capsys)
            assert code == 2, err
            assert len(err.splitlines()) == 1 and f"--out {out}: the folder is in use by " \
                f"another run (pid {os.getpid()})" in err  # fmt: skip
        assert _contents(out) == before
        # a run in another process is refused at once as well
        other = sil("run", scenario, "--mode", "inproc", "--out", str(out), timeout=120)
        assert other.returncode == 2
        assert other.stderr == (
            f"sil run: --out {out}: the folder is in use by another run (pid {os.getpid()}); "
            "wait for it to end or choose another folder\n"
        )
    assert not (out / run_folder.LOCK).exists()  # released, and removed
    code, _, err = _main(["run", scenario, "--mode", "inproc", "--out", str(out), "--no-plots"],
                         capsys)  # fmt: skip
    assert code == 0, err


def test_every_plot_a_run_may_write_is_a_run_file():
    source = (Path(__file__).parents[2] / "sil" / "analysis" / "plots.py").read_text()
    written = set(re.findall(r'out_dir / "([\w.]+)"', source))
    assert written and written <= set(results.PLOTS) <= set(results.RUN_FILES)
    for module in (Path(__file__).parents[2] / "sil" / "run").glob("*.py"):  # plots only there
        assert not re.findall(r'out_dir / "([\w.]+\.png)"', module.read_text()), module


def test_a_run_clears_every_file_an_earlier_run_or_replay_left(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    for name in results.RUN_FILES:
        (out / name).write_text("stale")
    (out / "notes.txt").write_text("mine")
    code, _, err = _main(
        ["run", str(_scenario(tmp_path)), "--mode", "inproc", "--out", str(out)], capsys
    )
    assert code == 0, err
    left = {p.name for p in out.iterdir() if p.read_bytes() == b"stale"}
    assert left == set(), left  # start.png, report.json, into_ecu.png, temporary files...
    assert (out / "notes.txt").read_text() == "mine"
    assert not any(p.name.startswith(results.TEMP_PREFIX) for p in out.iterdir())


def _no_space(*_args, **_kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_plot_that_cannot_be_written_aborts_the_flown_run_naming_it(
    tmp_path, capsys, monkeypatch
):
    from sil.analysis import plots

    def savefig_on_a_full_disk(path, writer):
        with results.atomic(path) as tmp:
            tmp.write_bytes(b"")  # the PNG begun
            _no_space()

    monkeypatch.setattr(plots, "write_with", savefig_on_a_full_disk)
    out = tmp_path / "run"
    code, _, err = _main(
        ["run", str(_scenario(tmp_path)), "--mode", "inproc", "--out", str(out)], capsys
    )
    assert code == 1
    reason = f"{out / 'speed.png'}: cannot write: No space left on device"
    assert err.splitlines() == [f"sil run: aborted: {reason}"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "aborted" and summary["abort_reason"] == reason
    assert summary["write_errors"] == [reason] and summary["sim_time_s"] > 1.9
    assert {"can.log", "trace.csv", "summary.json"} <= set(summary["kept"])
    assert not [p.name for p in out.iterdir() if p.suffix == ".png"]  # no empty PNG left
    assert not any(p.name.startswith(results.TEMP_PREFIX) for p in out.iterdir())


def test_a_summary_that_cannot_be_written_atomically_goes_over_the_running_one(
    tmp_path, capsys, monkeypatch
):
    write = results.write_atomically

    def full_for_the_final_summary(path, data):
        if path.name == "summary.json" and '"running"' not in str(data):
            with results.atomic(path):
                _no_space()
        return write(path, data)

    monkeypatch.setattr(results, "write_atomically", full_for_the_final_summary)
    out = tmp_path / "run"
    code, _, err = _main(
        ["run", str(_scenario(tmp_path)), "--mode", "inproc", "--out", str(out), "--no-plots"],
        capsys,
    )
    assert code == 1
    reason = f"{out / 'summary.json'}: cannot write: No space left on device"
    assert err.splitlines() == [f"sil run: aborted: {reason}"]
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary) == ["status", "abort_reason", "scenario", "write_errors", "kept"]
    assert summary["status"] == "aborted" and summary["abort_reason"] == reason
    assert "before the run began" not in reason


@pytest.fixture
def small_disk(tmp_path):
    """A 200 kB tmpfs (root only: skipped elsewhere), unmounted after the test."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=200k", "tmpfs", str(disk)], capture_output=True
    )
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.decode().strip()}")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def test_a_full_disk_names_the_file_and_leaves_no_empty_file(tmp_path, small_disk, sil):
    out = small_disk / "run"
    ran = sil("run", str(_scenario(tmp_path, 60.0)), "--mode", "inproc", "--out", str(out))
    assert ran.returncode == 1 and "Traceback" not in ran.stderr
    reason = f"{out / 'can.log'}: cannot write: No space left on device"
    assert ran.stderr.splitlines() == [f"sil run: aborted: {reason}"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "aborted" and summary["abort_reason"] == reason
    assert "before the run began" not in json.dumps(summary)
    assert summary["kept"] and "summary.json" in summary["kept"]
    assert not [p for p in out.iterdir() if p.suffix == ".png" or p.name.startswith(".tmp")]
    # two good runs elsewhere, compared onto the full disk; a replay's report there
    good = tmp_path / "good"
    assert sil("run", str(_scenario(tmp_path)), "--mode", "inproc", "--out", str(good),
                "--no-plots").returncode == 0  # fmt: skip
    compared = sil("compare", str(good), str(good), "--out", str(small_disk))
    assert compared.returncode == 1
    assert compared.stderr.splitlines() == [
        f"sil compare: {small_disk / 'compare.png'}: cannot write: No space left on device"
    ]
    replayed = sil("replay", str(good / "can.log"), "--into-ecu", "--out", str(small_disk))
    assert replayed.returncode == 1
    assert replayed.stderr.splitlines()[-1].startswith(f"sil replay: {small_disk / 'report.json'}")
    assert "cannot write: No space left on device" in replayed.stderr
    assert not [p for p in small_disk.iterdir() if p.suffix in (".png", ".json")]
