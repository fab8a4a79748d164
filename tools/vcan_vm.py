"""Run a command inside a throwaway virtual machine that has a real SocketCAN vcan0.

This machine's kernel has no CAN support, so `ip link add vcan0 type vcan` fails on the host.
virtme-ng boots Debian's stock kernel under QEMU with the host's root filesystem shared read-only
into the guest: the host's Python, the project's .venv and can-utils are all visible inside, and
folders given as rwdir are writable there (that is how a capture or a log comes back out).

    python -m tools.vcan_vm [--rwdir DIR] [--timeout S] [--cpus N] [--boot-console] -- COMMAND...

COMMAND runs in the guest as root, in the current directory, with vcan0 up. Its arguments are
quoted as given (use `-- sh -c '...'` for shell syntax). The exit status is the command's own;
when the VM cannot be started the status is 125 and one line on stderr says why.

The first run installs what is missing (as root): Debian's qemu-system-x86, linux-image-amd64,
busybox-static, can-utils, kmod and iproute2 with apt-get, and virtme-ng into the project's .venv
with pip. Later runs only check, in well under a second. KVM is not used (it does not boot on
these machines): the guest runs under software emulation, so vcan0 is up about 30 s after the
start (up to 50 s on a busy machine) and Python in the guest starts some 20 times slower.
"""

from __future__ import annotations

import argparse
import io
import os
import re
import shlex
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import NoReturn

from protocol import debian_packages
from protocol.debian_packages import tail as _tail

ROOT = Path(__file__).resolve().parent.parent
VENV_PYTHON = ROOT / ".venv" / "bin" / "python"
VNG = VENV_PYTHON.parent / "vng"

DEBIAN_PACKAGES = (
    "qemu-system-x86",
    "linux-image-amd64",
    "busybox-static",
    "can-utils",
    "kmod",
    "iproute2",
)
# The version whose options and exit-status handling this module was checked against.
VIRTME_NG = "virtme-ng==1.42"
GUEST_MEMORY = "1G"
# One vCPU: under software emulation a second one made both the boot and Python slower here.
GUEST_CPUS = 1
# udev in the guest would load drivers for every emulated device (KVM, crypto, SATA, CD-ROM,
# watchdog...), which takes about 15 s under software emulation and none of which vcan needs.
GUEST_MODULE_BLACKLIST = (
    "kvm_amd,kvm_intel,kvm,ccp,sr_mod,cdrom,sg,ahci,libata,iTCO_wdt,i6300esb,lpc_ich,i2c_i801,"
    "psmouse,pcspkr,serio_raw,evdev,powernow_k8,aesni_intel,sha512_ssse3,sha256_ssse3,sha1_ssse3,"
    "ghash_clmulni_intel,crc32_pclmul,crct10dif_pclmul,intel_pmc_bxt"
)
DEFAULT_TIMEOUT_S = 300.0
# Exit status of the command line tool when the VM could not be started (as `env` and `docker`).
EXIT_VM_FAILED = 125

BOOT_CONSOLE_HINT = "`python -m tools.vcan_vm --boot-console -- true` shows the guest's boot log"
_COMMAND = "command.sh"  # the command, as a shell script the guest runs
_READY = "ready"  # marker file: written by the guest once vcan0 is up, before the command
# Marker file: the command's exit status, written by the guest. vng 1.42 returns that status too,
# but also returns 255 when the guest died, which a command can return as well.
_STATUS = "status"


class VcanVmError(RuntimeError):
    """The VM could not be started or did not run the command to its end; str() says why."""


@dataclass(frozen=True)
class VmResult:
    """What one VM run gave: the command's exit status and its output (stdout and stderr)."""

    returncode: int
    output: str
    boot_s: float  # wall time from launching the VM until vcan0 was up in the guest
    wall_s: float  # wall time of the whole run, boot and shutdown included


def _log(message: str) -> None:
    print(f"vcan_vm: {message}", file=sys.stderr, flush=True)


def _install_debian_packages() -> None:
    # INITRD=No: the kernel's hook skips building an initramfs (about 50 s), which virtme-ng,
    # building its own, never reads.
    debian_packages.ensure(
        DEBIAN_PACKAGES,
        log=_log,
        error=VcanVmError,
        no_dpkg="dpkg-query not found: this tool needs a Debian-based host",
        env={"INITRD": "No"},
    )


def _installed_virtme_ng() -> str | None:
    probe = subprocess.run(
        [
            str(VENV_PYTHON),
            "-c",
            "import importlib.metadata as m; print(m.version('virtme-ng'))",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    return probe.stdout.strip() if probe.returncode == 0 else None


def _install_virtme_ng() -> None:
    if not VENV_PYTHON.exists():
        raise VcanVmError(f"project virtual environment missing: {VENV_PYTHON} (run dev.py setup)")
    wanted = VIRTME_NG.split("==")[1]
    if _installed_virtme_ng() == wanted and VNG.exists():
        return
    _log(f"installing {VIRTME_NG} into {VENV_PYTHON.parent.parent}")
    started = time.monotonic()
    done = subprocess.run(
        [str(VENV_PYTHON), "-m", "pip", "install", "-q", VIRTME_NG],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0 or not VNG.exists():
        raise VcanVmError(
            f"pip install {VIRTME_NG} failed (exit {done.returncode}): {_tail(done.stderr)}"
        )
    _log(f"installed {VIRTME_NG} in {time.monotonic() - started:.0f} s")


def ensure_prerequisites() -> None:
    """Install the Debian packages and virtme-ng when missing; quick when they are present."""
    _install_debian_packages()
    _install_virtme_ng()


def _version_key(kernel: Path) -> tuple[int, ...]:
    return tuple(int(part) for part in re.findall(r"\d+", kernel.name))


def find_kernel() -> Path:
    """The newest Debian amd64 kernel image in /boot that has its modules, vcan included."""
    images = sorted(Path("/boot").glob("vmlinuz-*-amd64"), key=_version_key, reverse=True)
    if not images:
        raise VcanVmError(
            "no kernel image /boot/vmlinuz-*-amd64 (apt-get install linux-image-amd64)"
        )
    for image in images:
        version = image.name.removeprefix("vmlinuz-")
        if any(Path("/lib/modules", version).rglob("vcan.ko*")):
            if not os.access(image, os.R_OK):
                raise VcanVmError(f"kernel image {image} is not readable (run as root)")
            return image
    raise VcanVmError(f"no vcan module in /lib/modules for kernels {[i.name for i in images]}")


def _guest_script(command: str, control: Path) -> str:
    """Shell text run in the guest: vcan0 up, then the command, with markers for the host.

    virtme-ng hands this text to the guest on the kernel command line, which x86 cuts at 2048
    bytes (the guest then hangs in its init): the command itself goes through a file in the
    control folder, so it may be as long as it likes.
    """
    script = control / _COMMAND
    script.write_text(command + "\n")
    ready = shlex.quote(str(control / _READY))
    status = shlex.quote(str(control / _STATUS))
    return (
        "modprobe vcan && ip link add dev vcan0 type vcan && ip link set up vcan0"
        f" || {{ echo 'vcan_vm: could not bring up vcan0 in the guest' >&2; exit 1; }}; "
        f"touch {ready}; "
        f"/bin/sh {shlex.quote(str(script))}; "
        f"echo $? > {status}"
    )


def _drain(stream: io.BufferedReader, chunks: list[bytes]) -> None:
    while chunk := stream.read1(65536):
        chunks.append(chunk)


def _kill_group(pgid: int) -> None:
    try:
        os.killpg(pgid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def run_in_vcan_vm(
    command: str,
    rwdir: Path | None = None,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    boot_console: bool = False,
    cpus: int = GUEST_CPUS,
) -> VmResult:
    """Boot a throwaway VM with vcan0 up, run the shell `command` as root there, return its result.

    `rwdir` is a host folder that the guest can write (at the same path); everything else of the
    host filesystem is read-only in the guest. The command runs in the current directory.
    `boot_console` puts the guest kernel's console into the output (to see why a boot fails).
    `cpus` is the number of virtual CPUs.
    Raises VcanVmError, with the reason, when the prerequisites cannot be installed, there is no
    kernel, the VM does not boot or bring up vcan0 in time, or the VM stops before the command
    has finished. Every process started here, QEMU included, is gone when this returns.
    """
    ensure_prerequisites()
    kernel = find_kernel()
    with tempfile.TemporaryDirectory(prefix="vcan_vm-") as scratch:
        control = Path(scratch)
        argv = [
            str(VNG),
            "--run",
            str(kernel),
            "--disable-kvm",
            # Bookworm's QEMU ships only the C virtiofsd, which virtme-ng tries and gives up on
            # after about 4 s: go straight to the 9p share of the host filesystem.
            "--force-9p",
            "--memory",
            GUEST_MEMORY,
            "--cpus",
            str(cpus),
            "--user",
            "root",
            "--append",
            f"modprobe.blacklist={GUEST_MODULE_BLACKLIST}",
            "--rwdir",
            str(control),
        ]
        if rwdir is not None:
            argv += ["--rwdir", str(Path(rwdir).resolve())]
        if boot_console:
            argv.append("--verbose")
        argv += ["--exec", _guest_script(command, control)]
        _log(f"booting {kernel.name} under QEMU without KVM (about 30 s)")
        started = time.monotonic()
        boot_s: float | None = None
        # One pipe for stdout and stderr: QEMU reopens the guest's stdout and stderr ports by
        # /proc/self/fd/N, and two opens of one regular file would overwrite each other.
        process = subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            # vng runs its helper virtme-run through the shell: .venv/bin goes on PATH.
            env={**os.environ, "PATH": f"{VNG.parent}{os.pathsep}{os.environ.get('PATH', '')}"},
        )
        chunks: list[bytes] = []
        assert process.stdout is not None
        reader = threading.Thread(target=_drain, args=(process.stdout, chunks), daemon=True)
        reader.start()
        try:
            while process.poll() is None:
                if boot_s is None and (control / _READY).exists():
                    boot_s = time.monotonic() - started
                if time.monotonic() - started > timeout_s:
                    stage = "booting the VM" if boot_s is None else "running the command"
                    raise VcanVmError(
                        f"timed out after {timeout_s:.0f} s while {stage};"
                        f" last output: {_tail(b''.join(chunks).decode(errors='replace'))}"
                    )
                time.sleep(0.1)
        finally:
            # vng forks QEMU into its own process group: nothing of it may outlive this call.
            _kill_group(process.pid)
            process.wait()
            reader.join()
            process.stdout.close()
        wall_s = time.monotonic() - started
        output = b"".join(chunks).decode(errors="replace")
        if not (control / _READY).exists():
            hint = "" if boot_console else f"; {BOOT_CONSOLE_HINT}"
            raise VcanVmError(
                f"the VM did not start or could not bring up vcan0 (vng exit {process.returncode}):"
                f" {_tail(output)}{hint}"
            )
        if not (control / _STATUS).exists():
            raise VcanVmError(
                f"the VM stopped before the command finished (vng exit {process.returncode}):"
                f" {_tail(output)}"
            )
        returncode = int((control / _STATUS).read_text().strip())
        return VmResult(
            returncode=returncode,
            output=output,
            boot_s=boot_s if boot_s is not None else wall_s,
            wall_s=wall_s,
        )


def _exit_on_sigterm(signum: int, _frame: FrameType | None) -> NoReturn:
    raise SystemExit(128 + signum)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tools.vcan_vm",
        description="Run COMMAND as root inside a throwaway VM with vcan0 up.",
    )
    parser.add_argument("--rwdir", type=Path, help="host folder the guest may write")
    parser.add_argument(
        "--boot-console", action="store_true", help="show the guest kernel's boot console too"
    )
    parser.add_argument(
        "--timeout", type=float, default=DEFAULT_TIMEOUT_S, help="seconds, boot included"
    )
    parser.add_argument(
        "--cpus", type=int, default=GUEST_CPUS, help=f"virtual CPUs (default {GUEST_CPUS})"
    )
    parser.add_argument("command", nargs=argparse.REMAINDER, help="-- COMMAND [ARG...]")
    args = parser.parse_args(argv)
    # SIGTERM (a CI cancelling, `timeout`) unwinds like Ctrl-C, so the VM is killed on the way out.
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("no COMMAND given")
    try:
        result = run_in_vcan_vm(
            shlex.join(command), args.rwdir, args.timeout, args.boot_console, args.cpus
        )
    except VcanVmError as error:
        print(f"vcan_vm: error: {error}", file=sys.stderr)
        return EXIT_VM_FAILED
    sys.stdout.write(result.output)
    _log(
        f"exit {result.returncode}; vcan0 up after {result.boot_s:.1f} s,"
        f" whole run {result.wall_s:.1f} s"
    )
    return result.returncode


if __name__ == "__main__":
    sys.exit(main())
