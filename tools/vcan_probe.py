"""Guest side of the real-vcan0 test: our frames on SocketCAN, a candump capture, one bad CRC.

Run inside the VM of :mod:`tools.vcan_vm` (vcan0 up, can-utils installed) on a folder the guest
may write, which holds ``plan.json`` from the host:

    python -m tools.vcan_probe DIR

``plan.json``: ``{"frames": [{"frame_id": int, "data": hex}, ...], "inject": {"frame_id": int,
"data_id": int, "frames": [hex, ...]}}``. The frames are encoded on the host with
:mod:`protocol.codec` (importing cantools, which the codec needs, takes about 15 s more in the
emulated guest than python-can alone). The probe

1. opens python-can's socketcan interface on vcan0 and starts ``candump -L vcan0`` writing
   ``DIR/capture.log``, and waits until the kernel lists candump's receiver on vcan0;
2. sends ``frames`` in order through python-can;
3. injects each of ``inject.frames`` with ``cansend``, receives it through python-can and runs the
   E2E checker (:class:`protocol.e2e.E2EChecker` for ``inject.data_id``) on it;
4. stops candump and writes ``DIR/result.json``: ``{"received": [hex, ...], "verdicts": [name,
   ...]}``, one entry per injected frame.

Exits non-zero with one line on stderr when any step fails.

    python -m tools.vcan_probe --capture FILE -- COMMAND...

runs COMMAND while ``candump -L vcan0`` writes FILE, and exits with COMMAND's status.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

from protocol.python_can import import_without_mf4

import_without_mf4()  # (seconds of the emulated guest's start)

import can  # noqa: E402

from protocol import strict_json  # noqa: E402
from protocol.e2e import E2EChecker  # noqa: E402

CHANNEL = "vcan0"
RECEIVE_TIMEOUT_S = 10.0
LISTEN_TIMEOUT_S = 10.0


class ProbeError(RuntimeError):
    """One step of the probe failed; str() says which and why."""


def raw_receivers(channel: str) -> int:
    """How many CAN_RAW receive filters the kernel holds for `channel` (sockets listening)."""
    table = Path("/proc/net/can/rcvlist_all")
    if not table.exists():  # the can module is not loaded yet: no CAN socket exists
        return 0
    lines = table.read_text().splitlines()
    return sum(1 for line in lines if line.split()[:1] == [channel])


def start_candump(capture: Path) -> subprocess.Popen[bytes]:
    """Start ``candump -L`` on CHANNEL into `capture`; return once its socket receives."""
    before = raw_receivers(CHANNEL)
    with open(capture, "wb") as out:
        candump = subprocess.Popen(["candump", "-L", CHANNEL], stdout=out)
    deadline = time.monotonic() + LISTEN_TIMEOUT_S
    while raw_receivers(CHANNEL) <= before:
        if candump.poll() is not None:
            raise ProbeError(f"candump exited with status {candump.returncode} before listening")
        if time.monotonic() > deadline:
            candump.kill()
            raise ProbeError(f"candump did not listen on {CHANNEL} within {LISTEN_TIMEOUT_S} s")
        time.sleep(0.05)
    return candump


def stop_candump(candump: subprocess.Popen[bytes]) -> None:
    candump.send_signal(signal.SIGINT)
    try:
        candump.wait(timeout=5)
    except subprocess.TimeoutExpired:
        candump.kill()
        raise ProbeError("candump did not stop on SIGINT") from None


def run(folder: Path) -> dict[str, list[str]]:
    plan = json.loads((folder / "plan.json").read_text())
    inject = plan["inject"]
    checker = E2EChecker(inject["data_id"])
    received: list[str] = []
    verdicts: list[str] = []
    with can.Bus(interface="socketcan", channel=CHANNEL) as bus:
        candump = start_candump(folder / "capture.log")
        try:
            for frame in plan["frames"]:
                bus.send(
                    can.Message(
                        arbitration_id=frame["frame_id"],
                        data=bytes.fromhex(frame["data"]),
                        is_extended_id=False,
                    )
                )
            for data in inject["frames"]:
                cansend = subprocess.run(
                    ["cansend", CHANNEL, f"{inject['frame_id']:03X}#{data}"],
                    capture_output=True,
                    text=True,
                )
                if cansend.returncode != 0:
                    raise ProbeError(f"cansend {data} failed: {cansend.stderr.strip()}")
                message = bus.recv(timeout=RECEIVE_TIMEOUT_S)
                if message is None:
                    raise ProbeError(f"frame {data} sent with cansend never reached python-can")
                if message.arbitration_id != inject["frame_id"]:
                    raise ProbeError(f"expected frame ID {inject['frame_id']:#x}, got {message}")
                received.append(bytes(message.data).hex().upper())
                verdicts.append(checker.check(message.data).name)
        finally:
            stop_candump(candump)
    return {"received": received, "verdicts": verdicts}


def capture_while(capture: Path, command: list[str]) -> int:
    """Run `command` while ``candump -L`` records everything on CHANNEL into `capture`."""
    candump = start_candump(capture)
    try:
        return subprocess.call(command)
    finally:
        stop_candump(candump)


USAGE = """usage: python -m tools.vcan_probe DIR
       python -m tools.vcan_probe --capture FILE -- COMMAND..."""


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) >= 4 and args[0] == "--capture" and args[2] == "--":
        try:
            return capture_while(Path(args[1]), args[3:])
        except (ProbeError, OSError) as error:
            print(f"vcan_probe: {error}", file=sys.stderr)
            return 1
    if len(args) != 1:
        print(USAGE, file=sys.stderr)
        return 2
    folder = Path(args[0])
    try:
        result = run(folder)
    except (ProbeError, OSError, can.CanError) as error:
        print(f"vcan_probe: {error}", file=sys.stderr)
        return 1
    (folder / "result.json").write_text(strict_json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
