"""Fixtures of the ground-support page's tests: an engine on a bench (a plant and an ECU in real
time on a loopback bus of the test's own, the ECU with a flash image), the page attached to it,
and headless Chromium (Debian's package, installed when missing) driven by Playwright."""

from __future__ import annotations

import os
import random
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from protocol import debian_packages

CHROMIUM = "/usr/bin/chromium"
# a browser on a machine with no network: nothing of its own on the network, no sandbox as root
CHROMIUM_ARGS = [
    "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]  # fmt: skip
START_S = 30.0


@dataclass
class Bench:
    spec: str
    url: str
    folder: Path
    processes: dict[str, subprocess.Popen]


def _spawn(folder: Path, name: str, *args: str) -> subprocess.Popen:
    log = (folder / f"{name}.log").open("w")
    return subprocess.Popen(
        [sys.executable, "-m", "sil.cli", *args], stdout=log, stderr=subprocess.STDOUT,
        cwd=folder, start_new_session=True,
    )  # fmt: skip


def _wait_for(folder: Path, name: str, pattern: str, process: subprocess.Popen) -> re.Match:
    deadline = time.monotonic() + START_S
    while time.monotonic() < deadline:
        found = re.search(pattern, (folder / f"{name}.log").read_text())
        if found:
            return found
        if process.poll() is not None:
            break
        time.sleep(0.1)
    pytest.fail(f"{name} did not start: {(folder / f'{name}.log').read_text()[-2000:]}")


@pytest.fixture(scope="module")
def bench(tmp_path_factory) -> Iterator[Bench]:
    """A plant at rest and the Python ECU in real time, and `sil gsu` attached to them."""
    folder = tmp_path_factory.mktemp("bench")
    rng = random.Random(os.getpid() ^ time.time_ns())
    group = f"239.255.{rng.randrange(1, 255)}.{rng.randrange(1, 255)}"
    spec = f"udp:{group}@{rng.randrange(20000, 60000)}"
    processes: dict[str, subprocess.Popen] = {}
    try:
        processes["plant"] = _spawn(folder, "plant", "plant", "--bus", spec, "--realtime",
                                    "--standstill")  # fmt: skip
        processes["ecu"] = _spawn(folder, "ecu", "ecu", "--bus", spec, "--mode", "realtime",
                                  "--flash", "ecu.flash")  # fmt: skip
        _wait_for(folder, "ecu", r"xcp: CAN IDs", processes["ecu"])
        processes["gsu"] = _spawn(folder, "gsu", "gsu", "--bus", spec, "--port", "0")
        url = _wait_for(folder, "gsu", r"http://\S+", processes["gsu"]).group(0)
        yield Bench(spec, url, folder, processes)
    finally:
        for process in reversed(processes.values()):
            process.terminate()
        for process in processes.values():
            try:
                process.wait(10)
            except subprocess.TimeoutExpired:
                process.kill()


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    """Headless Chromium from Debian, through Playwright."""
    try:
        debian_packages.ensure(("chromium",), log=lambda m: print(f"tests: {m}", file=sys.stderr))
    except debian_packages.DebianPackagesError as exc:
        pytest.fail(f"the browser tests need Debian's chromium: {exc}")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            yield chromium
        finally:
            chromium.close()
