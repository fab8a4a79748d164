"""The Debian packages the C port's checks need (clang for the warning check, the Arm toolchain
and newlib for the Cortex-M4 build, QEMU to run it), installed with apt-get when missing
(as root; otherwise the error says what to install). Used by the test set-up."""

from __future__ import annotations

import sys

from protocol import debian_packages

DEBIAN_PACKAGES = ("clang", "gcc-arm-none-eabi", "libnewlib-arm-none-eabi", "qemu-system-arm")
NO_DPKG = "dpkg-query not found: installing the toolchain needs a Debian host"


class ToolchainError(RuntimeError):
    """A package is missing and could not be installed."""


def _log(message: str) -> None:
    print(f"ecu.port: {message}", file=sys.stderr)


def missing_packages(packages: tuple[str, ...] = DEBIAN_PACKAGES) -> list[str]:
    return debian_packages.missing_packages(packages, error=ToolchainError, no_dpkg=NO_DPKG)


def ensure(packages: tuple[str, ...] = DEBIAN_PACKAGES) -> None:
    """Install the missing packages from Debian (as root), or raise saying which are missing."""
    debian_packages.ensure(packages, log=_log, error=ToolchainError, no_dpkg=NO_DPKG)
