"""A run that cannot start leaves an earlier run's folder as it was: what the ECU implementation
needs (the emulator and the image for ``--ecu-impl pil``, a C compiler for the C port of
``--ecu-impl c``) is found before the folder is touched, and its absence is named."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from tests.sil.test_run_folder import _contents, _main, _scenario


def _path_without(*programs: str) -> str:
    """$PATH without the folders that hold any of ``programs``."""
    folders = os.environ.get("PATH", "").split(os.pathsep)
    return os.pathsep.join(
        f for f in folders if f and not any((Path(f) / p).exists() for p in programs)
    )


@pytest.fixture
def completed_run(tmp_path, capsys) -> tuple[Path, Path, dict[str, bytes]]:
    """A scenario, a folder holding its completed run, and the folder's files."""
    scenario, out = _scenario(tmp_path), tmp_path / "run"
    code, _, err = _main(["run", str(scenario), "--mode", "inproc", "--out", str(out),
                          "--no-plots"], capsys)  # fmt: skip
    assert code == 0, err
    return scenario, out, _contents(out)


def test_pil_without_the_emulator_leaves_the_earlier_run(completed_run, monkeypatch, capsys):
    scenario, out, before = completed_run
    monkeypatch.setenv("PATH", _path_without("qemu-system-arm"))
    assert shutil.which("qemu-system-arm") is None
    code, _, err = _main(["run", str(scenario), "--ecu-impl", "pil", "--out", str(out)], capsys)
    assert code == 2
    assert "sil run: --ecu-impl pil: the emulator qemu-system-arm not found (apt-get install " \
        "qemu-system-arm)\n" in err  # fmt: skip
    assert _contents(out) == before


@pytest.mark.slow
@pytest.mark.parametrize(
    ("impl", "missing", "said"),
    [
        ("pil", ("qemu-system-arm",), "the emulator qemu-system-arm not found"),
        ("c", ("cc", "gcc", "clang"), "no C compiler found for the C port"),
    ],
)
def test_sil_run_refuses_a_missing_piece_before_the_folder(impl, missing, said, completed_run, sil):
    scenario, out, before = completed_run
    env = {k: v for k, v in os.environ.items() if k != "CC"}
    env["PATH"] = _path_without(*missing)
    done = sil("run", str(scenario), "--ecu-impl", impl, "--out", str(out), env=env, timeout=120)
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith(f"sil run: --ecu-impl {impl}: {said}"), done.stderr
    assert _contents(out) == before
