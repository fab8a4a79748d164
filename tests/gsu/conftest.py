"""Fixtures of the ground-support page's tests: an engine on a bench (a plant and an ECU in real
time on a loopback bus of the test's own, the ECU with a flash image, the page attached: the
bench's own station) and headless Chromium (Debian's package, installed when missing, as the
C port's toolchains are) driven by Playwright."""

from __future__ import annotations

import sys
from collections.abc import Iterator

import pytest

from protocol import debian_packages
from sil.bench import gsu


@pytest.fixture(scope="module")
def bench(tmp_path_factory) -> Iterator[gsu.Station]:
    """A plant at rest and the Python ECU in real time, and `sil gsu` attached to them."""
    with gsu.station(tmp_path_factory.mktemp("bench")) as station:
        yield station


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    """Headless Chromium from Debian, through Playwright."""
    try:
        debian_packages.ensure(("chromium",), log=lambda m: print(f"tests: {m}", file=sys.stderr))
    except debian_packages.DebianPackagesError as exc:
        pytest.fail(f"the browser tests need Debian's chromium: {exc}")
    with gsu.chromium() as chromium:
        yield chromium
