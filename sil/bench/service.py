"""`sil bench service`: frame throughput of the service port on a pseudo-terminal and the time
the port takes inside one ECU tick.

The ECU side runs here (the Python firmware with a running engine's inputs, its service port on a
new pty); a client runs in another process, as `sil console` would:

- link: live-data frames written to the pty as fast as it takes them, decoded by the client:
  what the pseudo-terminal and the frame decoder carry;
- stream: the port polled free-running (no tick period) and streaming a live sample every tick;
  the client decodes what arrives: frames and bytes per second, samples lost;
- requests: the same loop answering back-to-back parameter reads: round trips per second;
- budget: ticks at 100 Hz in real time, streaming at 50 Hz while the client reads and writes
  parameters and the fault log without pause: worst, 99th-percentile and mean time of the port's
  poll in one tick, in wall time (on a busy machine its tail is the operating system preempting
  the process) and the most CPU time one poll took; and how many polls gave up the CPU in the
  kernel (voluntary context switches: the descriptors are non-blocking, so these are waits on the
  pty's own locks while the client reads it at the same moment, or on page faults).
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time

from ecu.firmware import E2E_OK, Ecu, EcuInputs
from ecu.params import EcuParams
from ecu.service import live
from ecu.service.framing import encode_frame
from ecu.service.message import Kind, Message, Service, Status, pack
from ecu.service.port import ServicePort, boot
from ecu.service.transport import open_pty

CLIENT = """
import json, sys, time
from ecu.service.transport import open_transport
from sil.console.client import ServiceClient

mode, seconds = sys.argv[2], float(sys.argv[3])
c = ServiceClient(open_transport(sys.argv[1]), timeout_s=5.0, retries=0)
out = {}
if mode == "link":
    print("ready", flush=True)
    read, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        data = c.transport.read(65536)
        read += len(data)
        c.decoder.feed(data)
    dt = time.perf_counter() - t0
    print(json.dumps({"frames_s": c.decoder.stats.frames / dt, "bytes_s": read / dt}))
    sys.exit(0)
c.identify()
if mode == "stream":
    c.stream(100)
    frames0, t0 = c.decoder.stats.frames, time.perf_counter()
    read = 0
    while time.perf_counter() - t0 < seconds:
        data = c.transport.read(65536)
        read += len(data)
        c.decoder.feed(data)
        time.sleep(0.0005)
    dt = time.perf_counter() - t0
    out = {"frames_s": (c.decoder.stats.frames - frames0) / dt, "bytes_s": read / dt}
    c.stream(0)
elif mode == "requests":
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        c.get("pid_kp")
        n += 1
    out = {"round_trips_s": n / (time.perf_counter() - t0)}
else:
    c.stream(50)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        c.set("pid_kp", 2.0 + (n % 8) / 8)
        c.get("egt_limit_k")
        c.faults()
        c.receive()
        n += 1
    out = {"cycles": n, "gaps": c.stream_gaps}
c.stream(0)
print(json.dumps(out), flush=True)
"""


def _running_inputs() -> EcuInputs:
    i = EcuInputs()
    i.sensor_status = i.analog_status = i.demand_status = E2E_OK
    i.speed_rpm, i.egt_dk, i.supply_mv, i.pump_ma = 100_890, 10_480, 22_200, 1_500
    i.demand_cpct, i.arm = 8_968, 1
    return i


def _session(mode: str, seconds: float, period_s: float | None) -> tuple[dict, list[float], dict]:
    """Serve one client process; returns its figures, each poll's duration and the port's
    counters."""
    params = EcuParams()
    booted = boot(params, None)
    ecu = Ecu(booted.table.firmware)
    transport = open_pty()
    port = ServicePort(transport, ecu, booted, seed=1)
    i = _running_inputs()
    client = subprocess.Popen(
        [sys.executable, "-c", CLIENT, transport.name, mode, str(seconds)],
        stdout=subprocess.PIPE,
        text=True,
    )
    polls: list[float] = []
    blocked = 0  # polls during which this thread waited in the kernel
    clock = time.perf_counter
    next_tick = clock()
    while client.poll() is None:
        if period_s is not None:
            next_tick += period_s
            time.sleep(max(0.0, next_tick - clock()))
        waits = resource.getrusage(resource.RUSAGE_THREAD).ru_nvcsw
        t0 = clock()
        port.poll(i)
        polls.append(clock() - t0)
        blocked += resource.getrusage(resource.RUSAGE_THREAD).ru_nvcsw != waits
        i.sensor_status = i.analog_status = i.demand_status = E2E_OK
        ecu.tick(i)
    out = client.stdout.read()
    transport.close()
    if client.returncode != 0:
        raise RuntimeError(f"bench client ({mode}) exited with {client.returncode}")
    return json.loads(out), polls, {**port.summary(), "blocked": blocked}


def _link(seconds: float) -> dict:
    """Frames pushed to a pty as fast as it takes them; the client's decoded rate."""
    transport = open_pty()
    ecu = Ecu(EcuParams())
    i = _running_inputs()
    for _ in range(20):  # a running engine: realistic values, realistic frame lengths
        ecu.tick(i)
    sample = Message(Kind.STREAM, 1, Service.STREAM, Status.OK, live.sample(ecu, 0))
    block = encode_frame(pack(sample)) * 64
    client = subprocess.Popen(
        [sys.executable, "-c", CLIENT, transport.name, "link", str(seconds)],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert client.stdout is not None
    if client.stdout.readline() != "ready\n":
        raise RuntimeError("bench client (link) did not start")
    offset = 0
    while client.poll() is None:
        offset = (offset + transport.write(block[offset:])) % len(block)
    figures = json.loads(client.stdout.read())
    transport.close()
    return {**figures, "frame_bytes": len(block) // 64}


def run(quick: bool = False) -> dict:
    seconds = 1.0 if quick else 3.0
    link = _link(seconds)
    stream, _, streamed = _session("stream", seconds, None)
    requests, _, _ = _session("requests", seconds, None)
    budget, polls, port = _session("budget", seconds, 0.01)
    polls.sort()
    return {
        "pty_link_frames_per_s": round(link["frames_s"]),
        "pty_link_bytes_per_s": round(link["bytes_s"]),
        "live_frame_bytes": link["frame_bytes"],
        "pty_stream_frames_per_s": round(stream["frames_s"]),
        "pty_stream_bytes_per_s": round(stream["bytes_s"]),
        "pty_stream_frames_dropped_by_ecu": streamed["tx_dropped"],
        "pty_request_round_trips_per_s": round(requests["round_trips_s"]),
        "budget_ticks": len(polls),
        "budget_client_cycles": budget["cycles"],
        "budget_stream_samples_lost": budget["gaps"],
        "service_worst_us_per_tick": round(polls[-1] * 1e6, 1),
        "service_worst_cpu_us_per_tick": port["worst_cpu_us"],
        "service_p99_us_per_tick": round(polls[int(0.99 * (len(polls) - 1))] * 1e6, 1),
        "service_mean_us_per_tick": round(sum(polls) / len(polls) * 1e6, 1),
        "service_mean_cpu_us_per_tick": port["mean_cpu_us"],
        "service_polls_that_blocked": port["blocked"] + streamed["blocked"],
    }
