"""The compiled tick (ecu.compiled_tick): in use when built from the sources as they are, never
when they changed since, and bit for bit the interpreted tick: every input, output and the
state's digest on every tick of golden vectors that cover the controllers, the start and stop
sequence, the modes and the faults."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import ecu
from ecu import compiled_tick, firmware

VECTORS = ("start-stop", "modes", "faults", "mrac-aero", "pi-staircase", "bench-tests")


def test_the_session_runs_the_compiled_tick() -> None:
    assert ecu.COMPILED and compiled_tick.in_use(), (
        f"no current build in {compiled_tick.BUILD_DIR}: python -m ecu.build_tick build"
    )
    assert Path(firmware.__file__).parent == compiled_tick.BUILD_DIR / "ecu"
    assert compiled_tick.source_file(firmware) == compiled_tick.PACKAGE / "firmware.py"


def _vectors(folder: Path, pure: bool) -> dict[str, bytes]:
    env = {k: v for k, v in os.environ.items() if k != compiled_tick.PURE_ENV}
    if pure:
        env[compiled_tick.PURE_ENV] = "1"
    code = (
        "import sys; from ecu import compiled_tick; from sil.run import golden\n"
        f"assert compiled_tick.in_use() is {not pure}, 'which tick runs'\n"
        "sys.exit(golden.main(sys.argv[1:]))"
    )
    done = subprocess.run([sys.executable, "-c", code, str(folder), *VECTORS], env=env,
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    return {name: (folder / f"{name}.gv").read_bytes() for name in VECTORS}


def test_compiled_and_interpreted_ticks_are_the_same_on_every_tick(tmp_path: Path) -> None:
    compiled = _vectors(tmp_path / "compiled", pure=False)
    interpreted = _vectors(tmp_path / "interpreted", pure=True)
    for name in VECTORS:
        assert len(compiled[name]) > 4_000, name  # (rows of ticks, not an empty file)
        assert compiled[name] == interpreted[name], name


def test_a_build_of_other_sources_is_not_used(tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    monkeypatch.delenv(compiled_tick.PURE_ENV, raising=False)
    monkeypatch.setattr(compiled_tick, "BUILD_DIR", tmp_path)
    monkeypatch.setattr(sys, "path", list(sys.path))
    path: list[str] = ["ecu-sources"]
    assert not compiled_tick.activate(path) and path == ["ecu-sources"]  # none built
    (tmp_path / compiled_tick.STAMP).write_text("0" * 64 + " 1.0\n")  # built from others
    assert not compiled_tick.current() and not compiled_tick.activate(path)
    (tmp_path / compiled_tick.STAMP).write_text(f"{compiled_tick.digest()} 1.0\n")
    monkeypatch.setenv(compiled_tick.PURE_ENV, "1")
    assert not compiled_tick.activate(path)  # asked for the interpreted tick
    monkeypatch.delenv(compiled_tick.PURE_ENV)
    assert compiled_tick.activate(path) and path == [str(tmp_path / "ecu"), "ecu-sources"]


def test_a_changed_source_changes_the_digest(tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    for name in compiled_tick.MODULES + compiled_tick.READ:
        (tmp_path / f"{name}.py").write_bytes((compiled_tick.PACKAGE / f"{name}.py").read_bytes())
    monkeypatch.setattr(compiled_tick, "PACKAGE", tmp_path)
    before = compiled_tick.digest()
    with (tmp_path / "limiters.py").open("a") as f:
        f.write("\n")
    assert compiled_tick.digest() != before


def test_every_record_declares_the_fields_it_lists() -> None:
    """A record's ``FIELDS`` (what the C layouts, the golden rows and the digests iterate) are
    its annotated attributes (what the compiled class holds), in the same order."""
    records = 0
    for name in compiled_tick.MODULES + compiled_tick.READ:
        tree = ast.parse((compiled_tick.PACKAGE / f"{name}.py").read_text())
        for cls in (n for n in tree.body if isinstance(n, ast.ClassDef)):
            listed = [n for n in cls.body if isinstance(n, ast.AnnAssign)
                      and isinstance(n.target, ast.Name) and n.target.id == "FIELDS"]  # fmt: skip
            if not listed:
                continue
            records += 1
            fields = ast.literal_eval(listed[0].value)  # type: ignore[arg-type]
            declared = [n.target.id for n in cls.body if isinstance(n, ast.AnnAssign)
                        and isinstance(n.target, ast.Name) and n.target.id != "FIELDS"]  # fmt: skip
            assert declared == list(fields), f"{name}.{cls.name}"
    assert records == 6  # inputs, outputs, tick variables, state, parameters, the sequencer's
