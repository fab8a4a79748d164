"""`sil bench gsu`: the ground-support page's update rate and its latency from frame to screen,
and the time it takes to read the ECU's parameters, in a real browser.

An engine on a bench as a user sets it up: `sil plant --realtime --standstill`, `sil ecu --mode
realtime --flash` (the Python ECU; with --full also the C node and the firmware image in the
loop, which has no flash) and `sil gsu`, each a process on a loopback bus of the bench's own;
headless Chromium (Debian's, driven by Playwright) opens the page. The engine is started from
the page's API and held at 70 %N; then, for the bench's time, the page counts what it shows:
screen updates a second, and for each the age of the newest sensor frame it shows (from its
arrival at the page's server to the screen: the server's stream, the browser's event loop and
the drawing).
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from sil.bench.common import BenchError

IMPLS = ("python", "c", "pil")  # the quick bench: the first
SECONDS, QUICK_S = 30.0, 10.0
START_S = 60.0  # from standstill to RUN, at most
PIL_BUILD_S = 300.0  # the firmware image is compiled at its first use
TARGETS = {"updates_per_s": 10.0, "latency_p95_ms": 100.0}
TARGET_TEXT = {
    "targets": f"the page: >= {TARGETS['updates_per_s']:g} screen updates a second and frame to "
    f"screen p95 <= {TARGETS['latency_p95_ms']:g} ms, with the Python ECU (quick) or each ECU"
}
CHROMIUM = "/usr/bin/chromium"
# a browser on a machine with no network: nothing of its own on the network, no sandbox as root
CHROMIUM_ARGS = (
    "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
)  # fmt: skip


@dataclass
class Station:
    """An engine on a bench with the page attached: the bus, the page's address, the folder
    the processes run in (their logs, the flash image, recordings)."""

    spec: str
    url: str
    folder: Path
    processes: dict[str, subprocess.Popen]

    def api(self, path: str, body: dict | None = None) -> object:
        """The page's API, with the session's token (urllib.error.HTTPError on a refusal)."""
        token = self.url.split("token=", 1)[1]
        headers = {"X-GSU-Token": token, "Content-Type": "application/json"}
        data = None if body is None else json.dumps(body).encode()
        base = self.url.split("/?", 1)[0]
        request = urllib.request.Request(base + path, data=data, headers=headers)
        with urllib.request.urlopen(request, timeout=30) as response:
            return json.loads(response.read())


def _spawn(folder: Path, name: str, *args: str) -> subprocess.Popen:
    with (folder / f"{name}.log").open("w") as log:
        return subprocess.Popen(
            [sys.executable, "-m", "sil.cli", *args], stdout=log, stderr=subprocess.STDOUT,
            cwd=folder, start_new_session=True,
        )  # fmt: skip


def _wait_for(
    folder: Path, name: str, pattern: str, process: subprocess.Popen, timeout_s: float = 30.0
) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        found = re.search(pattern, (folder / f"{name}.log").read_text())
        if found:
            return found.group(0)
        if process.poll() is not None:
            break
        time.sleep(0.1)
    tail = (folder / f"{name}.log").read_text().strip().splitlines()[-3:]
    raise BenchError(f"sil {name} did not start: {tail}")


@contextlib.contextmanager
def station(folder: Path, impl: str = "python") -> Iterator[Station]:
    """A plant at rest and an ECU (``impl``) in real time with a flash image (but the image in
    the loop), and `sil gsu` attached to them, on a loopback bus of their own; all stopped on
    the way out."""
    rng = random.Random(os.getpid() ^ time.time_ns())
    group = f"239.255.{rng.randrange(1, 255)}.{rng.randrange(1, 255)}"
    spec = f"udp:{group}@{rng.randrange(20000, 60000)}"
    processes: dict[str, subprocess.Popen] = {}
    try:
        processes["plant"] = _spawn(folder, "plant", "plant", "--bus", spec, "--realtime",
                                    "--standstill")  # fmt: skip
        flash = () if impl == "pil" else ("--flash", "ecu.flash")
        processes["ecu"] = _spawn(folder, "ecu", "ecu", "--impl", impl, "--bus", spec, "--mode",
                                  "realtime", *flash)  # fmt: skip
        _wait_for(folder, "ecu", r"xcp: CAN IDs", processes["ecu"], PIL_BUILD_S)
        processes["gsu"] = _spawn(folder, "gsu", "gsu", "--bus", spec, "--port", "0", "--impl",
                                  impl)  # fmt: skip
        url = _wait_for(folder, "gsu", r"http://\S+", processes["gsu"])
        yield Station(spec, url, folder, processes)
    finally:
        for process in reversed(processes.values()):
            with contextlib.suppress(ProcessLookupError):
                process.send_signal(signal.SIGTERM)
        for process in processes.values():
            try:
                process.wait(15)
            except subprocess.TimeoutExpired:
                process.kill()


@contextlib.contextmanager
def chromium() -> Iterator[object]:
    """Headless Chromium from Debian through Playwright (BenchError saying what is missing)."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        raise BenchError("the page's bench needs Playwright: pip install playwright") from None
    if not Path(CHROMIUM).exists():
        raise BenchError(f"the page's bench needs Debian's chromium ({CHROMIUM}): apt-get "
                         "install --no-install-recommends chromium")  # fmt: skip
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True,
                                    args=list(CHROMIUM_ARGS))  # fmt: skip
        try:
            yield browser
        finally:
            browser.close()


def _until(what: str, condition, timeout_s: float) -> None:  # noqa: ANN001
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise BenchError(f"{what}: not within {timeout_s:g} s")
        time.sleep(0.2)


def _case(browser, impl: str, seconds: float, folder: Path) -> dict:  # noqa: ANN001
    with station(folder, impl) as bench:
        page = browser.new_page()
        page.goto(bench.url)
        bench.api("/api/unlock", {})
        bench.api("/api/start", {"confirm": True})
        _until("the engine in RUN", lambda: bench.api("/api/state").get("state") == "RUN", START_S)
        bench.api("/api/throttle", {"pct": 70})
        time.sleep(5.0)
        page.evaluate("() => { window.gsuStats.latencies.length = 0; }")
        drawn0 = page.evaluate("() => window.gsuStats.drawn")
        time.sleep(seconds)
        stats = page.evaluate("() => ({n: window.gsuStats.drawn, lat: window.gsuStats.latencies})")
        started = time.perf_counter()
        params = bench.api("/api/params")
        read_s = time.perf_counter() - started
        bench.api("/api/stop", {})
        page.close()
    latencies = sorted(stats["lat"])
    if not latencies:
        raise BenchError(f"{impl}: the page showed no sensor frame")
    return {
        f"{impl}_updates_per_s": round((stats["n"] - drawn0) / seconds, 1),
        f"{impl}_latency_median_ms": round(statistics.median(latencies), 1),
        f"{impl}_latency_p95_ms": round(latencies[int(0.95 * (len(latencies) - 1))], 1),
        f"{impl}_latency_max_ms": round(latencies[-1], 1),
        f"{impl}_read_parameters_s": round(read_s, 2),
        f"{impl}_parameters": len(params),  # type: ignore[arg-type]
    }


def run(quick: bool = False) -> dict:
    seconds = QUICK_S if quick else SECONDS
    impls = IMPLS[:1] if quick else IMPLS
    figures: dict = {"seconds_per_case": seconds, "cpus": os.cpu_count()}
    with chromium() as browser, tempfile.TemporaryDirectory() as tmp:
        for impl in impls:
            folder = Path(tmp) / impl
            folder.mkdir()
            figures.update(_case(browser, impl, seconds, folder))
    figures["targets"] = (
        f"at least {TARGETS['updates_per_s']:g} screen updates a second, frame-to-screen latency "
        f"p95 <= {TARGETS['latency_p95_ms']:g} ms, each ECU"
    )
    figures["targets_met"] = all(
        figures[f"{impl}_updates_per_s"] >= TARGETS["updates_per_s"]
        and figures[f"{impl}_latency_p95_ms"] <= TARGETS["latency_p95_ms"]
        for impl in impls
    )
    return figures
