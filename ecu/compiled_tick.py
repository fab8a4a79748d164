"""The firmware tick compiled to C extension modules (mypyc) from the same Python source.

The tick's modules (:data:`MODULES`) are typed Python; mypyc compiles exactly that source, so
the compiled tick computes what the interpreted one does, bit for bit (Python's integers either
way), in about half the time. Nothing else changes: the source stays the reference, and a
machine without a C compiler runs it as it is.

``python -m ecu.build_tick`` builds into :data:`BUILD_DIR` and stamps the build with a
digest of the sources it was compiled from and those they read (:func:`digest`);
``ecu/__init__.py`` puts the build in front
of the package's own modules only while that digest still matches, so an edited source is
never shadowed by an older build: it runs interpreted until built again (``dev.py`` builds
whenever the digest changed). ``TURBOJET_PURE_PYTHON=1`` runs the interpreted tick regardless.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
from pathlib import Path
from types import ModuleType

PACKAGE = Path(__file__).resolve().parent
BUILD_DIR = PACKAGE.parent / "build" / "compiled-tick"
STAMP = "stamp"
PURE_ENV = "TURBOJET_PURE_PYTHON"
# the modules of one tick (ecu.firmware.Ecu.tick and what it calls), compiled together
MODULES = (
    "fixedpoint", "state", "estimator", "fast_model", "limiters",
    "modes", "start_sequencer", "pi", "pid", "rate_filter", "inlet", "faults", "pump_driver",
    "tables", "mrac", "actuator_tests", "logbook", "firmware",
)  # fmt: skip


class BuildError(Exception):
    """The compiled tick could not be built (the reason, with the compiler's last lines)."""


# what the compiled modules take their types and constants from, beside themselves
READ = ("params", "firmware_params")


def digest() -> str:
    """What a build is valid for: the sources it was compiled from and those they read (a
    module's constants may be compiled into another), and the Python ABI."""
    h = hashlib.sha256(sysconfig.get_config_var("EXT_SUFFIX").encode())
    for name in sorted(MODULES + READ):
        h.update(name.encode() + b"\0" + (PACKAGE / f"{name}.py").read_bytes())
    return h.hexdigest()


def current() -> bool:
    """A build is there and was made from the sources as they are now."""
    stamp = BUILD_DIR / STAMP
    return stamp.exists() and stamp.read_text().split()[:1] == [digest()]


def activate(package_path: list[str]) -> bool:
    """Put a current build in front of the package's modules (from ``ecu/__init__.py``);
    False (the interpreted tick) when there is none, it is stale, or :data:`PURE_ENV` is set."""
    if os.environ.get(PURE_ENV) or not current():
        return False
    package_path.insert(0, str(BUILD_DIR / "ecu"))
    if str(BUILD_DIR) not in sys.path:
        sys.path.append(str(BUILD_DIR))  # (mypyc's shared library of the group)
    return True


def source_file(module: ModuleType) -> Path:
    """A module's source file, a compiled module's too (whose ``__file__`` is its build's)."""
    path = Path(str(module.__file__))
    return path if path.suffix == ".py" else PACKAGE / f"{module.__name__.rsplit('.', 1)[-1]}.py"


def in_use() -> bool:
    """The tick this process runs is the compiled one."""
    from ecu import firmware

    return Path(firmware.__file__).suffix != ".py"


def build(quiet: bool = False) -> float:
    """Compile :data:`MODULES` into :data:`BUILD_DIR`; the seconds it took. BuildError when
    mypyc is missing or refuses (a type error in the tick's source), or no compiler works."""
    try:
        from mypy.version import __version__ as mypy_version
    except ImportError:
        raise BuildError("mypyc is not installed (pip install mypy)") from None
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="ecu-tick-build-") as tmp:
        work = Path(tmp)
        (work / "ecu").mkdir()
        for path in PACKAGE.glob("*.py"):
            shutil.copy2(path, work / "ecu" / path.name)
        sources = [f"ecu/{name}.py" for name in MODULES]
        done = subprocess.run(
            [sys.executable, "-m", "mypyc", *sources], cwd=work, capture_output=True, text=True,
            env={**os.environ, "MYPYC_OPT_LEVEL": "3"}, check=False,
        )  # fmt: skip
        if done.returncode != 0:
            said = [line for line in (done.stdout + done.stderr).splitlines() if line.strip()]
            raise BuildError("mypyc failed:\n  " + "\n  ".join(said[-12:]))
        suffix = sysconfig.get_config_var("EXT_SUFFIX")
        built = [work / "ecu" / f"{Path(s).stem}{suffix}" for s in sources]
        shared = list(work.glob(f"*__mypyc{suffix}"))
        missing = [p.name for p in built if not p.exists()]
        if missing:
            raise BuildError(f"mypyc made no {', '.join(missing)}")
        fresh = BUILD_DIR.with_name(BUILD_DIR.name + ".new")
        shutil.rmtree(fresh, ignore_errors=True)
        (fresh / "ecu").mkdir(parents=True)
        for path in built:
            shutil.copy2(path, fresh / "ecu" / path.name)
        for path in shared:
            shutil.copy2(path, fresh / path.name)
        shutil.rmtree(BUILD_DIR, ignore_errors=True)
        fresh.rename(BUILD_DIR)
    (BUILD_DIR / STAMP).write_text(f"{digest()} {mypy_version}\n")
    spent = time.monotonic() - started
    if not quiet:
        print(f"ecu.build_tick: built {len(built)} modules into {BUILD_DIR} in {spent:.0f} s")
    return spent
