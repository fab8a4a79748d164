"""Fixtures of the C port tests: fresh golden vectors from the current Python firmware (once per
session) and the toolchains, installed from Debian when missing (a failure says why)."""

from __future__ import annotations

from pathlib import Path

import pytest

from ecu import golden
from ecu.port import toolchain
from sil.run import golden as sources


@pytest.fixture(scope="session")
def vectors(tmp_path_factory) -> dict[str, tuple[Path, golden.Golden]]:
    """Every golden vector of sil.run.golden.SOURCES, recorded now: name -> (file, vectors)."""
    out = tmp_path_factory.mktemp("golden")
    found = {}
    for name in sources.SOURCES:
        g = sources.record(name)
        path = out / f"{name}.gv"
        golden.write(g, path)
        found[name] = (path, g)
    return found


@pytest.fixture(scope="session")
def toolchains() -> None:
    """clang, arm-none-eabi-gcc with newlib and qemu-system-arm (apt-get as root if missing)."""
    try:
        toolchain.ensure()
    except toolchain.ToolchainError as exc:
        pytest.fail(f"C port toolchains: {exc}")
