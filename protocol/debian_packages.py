"""Debian packages a part of the project needs, installed with apt-get when missing: as root it
installs them, otherwise the error says what to run. Used by the C port's toolchain check
(ecu/port/toolchain.py) and the vcan VM (tools/vcan_vm.py); it lives here because both may import
protocol (tests/test_layers.py), and it uses nothing of ours."""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from collections.abc import Callable, Mapping


class DebianPackagesError(RuntimeError):
    """A package is missing and could not be installed; str() says why."""


NO_DPKG = "dpkg-query not found: installing the packages needs a Debian host"


def tail(text: str, count: int = 3) -> str:
    """The last ``count`` non-empty lines of ``text`` on one line."""
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return " | ".join(lines[-count:]) if lines else "(no output)"


def missing_packages(
    packages: tuple[str, ...],
    *,
    error: type[Exception] = DebianPackagesError,
    no_dpkg: str = NO_DPKG,
) -> list[str]:
    """The ``packages`` dpkg does not have installed, in their order (``error(no_dpkg)`` when
    this is no Debian host)."""
    if shutil.which("dpkg-query") is None:
        raise error(no_dpkg)
    query = subprocess.run(
        ["dpkg-query", "-W", "-f=${Package} ${db:Status-Status}\n", *packages],
        capture_output=True,
        text=True,
        check=False,
    )
    installed = {
        name
        for name, _, status in (line.partition(" ") for line in query.stdout.splitlines())
        if status == "installed"
    }
    return [name for name in packages if name not in installed]


def apt_get(
    *args: str,
    env: Mapping[str, str] | None = None,
    error: type[Exception] = DebianPackagesError,
) -> None:
    """apt-get ARGS, non-interactive, waiting up to 5 minutes for the dpkg lock (``env``: added
    to the environment)."""
    full_env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive", **(env or {})}
    done = subprocess.run(
        ["apt-get", "-q", "-o", "DPkg::Lock::Timeout=300", *args],
        capture_output=True,
        text=True,
        env=full_env,
        check=False,
    )
    if done.returncode != 0:
        raise error(f"apt-get {args[0]} failed (exit {done.returncode}): {tail(done.stderr)}")


def ensure(
    packages: tuple[str, ...],
    *,
    log: Callable[[str], None],
    error: type[Exception] = DebianPackagesError,
    no_dpkg: str = NO_DPKG,
    env: Mapping[str, str] | None = None,
) -> None:
    """Install the missing ``packages`` from Debian (as root), or raise ``error`` saying which
    are missing and how to install them. ``log``: progress lines; ``env``: added to apt-get's
    environment."""
    missing = missing_packages(packages, error=error, no_dpkg=no_dpkg)
    if not missing:
        return
    if os.geteuid() != 0:
        raise error(
            f"Debian packages missing and not root to install them: {' '.join(missing)}"
            f" (run: sudo apt-get install --no-install-recommends {' '.join(missing)})"
        )
    log(f"installing Debian packages: {' '.join(missing)}")
    started = time.monotonic()
    apt_get("update", env=env, error=error)
    apt_get("install", "-y", "--no-install-recommends", *missing, env=env, error=error)
    still = missing_packages(packages, error=error, no_dpkg=no_dpkg)
    if still:
        raise error(f"Debian packages still missing after apt-get: {' '.join(still)}")
    log(f"installed Debian packages in {time.monotonic() - started:.0f} s")
