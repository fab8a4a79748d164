"""The Debian packages the C port's checks need (clang for the warning check, the Arm toolchain
and newlib for the Cortex-M4 build, QEMU to run it), installed with apt-get when missing
(as root; otherwise the error says what to install). Used by the test set-up."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time

DEBIAN_PACKAGES = ("clang", "gcc-arm-none-eabi", "libnewlib-arm-none-eabi", "qemu-system-arm")


class ToolchainError(RuntimeError):
    """A package is missing and could not be installed."""


def _tail(text: str, count: int = 3) -> str:
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return " | ".join(lines[-count:]) if lines else "(no output)"


def missing_packages(packages: tuple[str, ...] = DEBIAN_PACKAGES) -> list[str]:
    if shutil.which("dpkg-query") is None:
        raise ToolchainError("dpkg-query not found: installing the toolchain needs a Debian host")
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


def _apt_get(*args: str) -> None:
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    done = subprocess.run(
        ["apt-get", "-q", "-o", "DPkg::Lock::Timeout=300", *args],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    if done.returncode != 0:
        raise ToolchainError(
            f"apt-get {args[0]} failed (exit {done.returncode}): {_tail(done.stderr)}"
        )


def ensure(packages: tuple[str, ...] = DEBIAN_PACKAGES) -> None:
    """Install the missing packages from Debian (as root), or raise saying which are missing."""
    missing = missing_packages(packages)
    if not missing:
        return
    if os.geteuid() != 0:
        raise ToolchainError(
            f"Debian packages missing and not root to install them: {' '.join(missing)}"
            f" (run: sudo apt-get install --no-install-recommends {' '.join(missing)})"
        )
    print(f"ecu.port: installing Debian packages: {' '.join(missing)}", file=sys.stderr)
    started = time.monotonic()
    _apt_get("update")
    _apt_get("install", "-y", "--no-install-recommends", *missing)
    still = missing_packages(packages)
    if still:
        raise ToolchainError(f"Debian packages still missing after apt-get: {' '.join(still)}")
    print(f"ecu.port: installed in {time.monotonic() - started:.0f} s", file=sys.stderr)
