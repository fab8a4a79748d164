"""Build the C port: the host shared library (for ctypes), the host golden-vector replayer, the
Cortex-M4 replay firmware and the Cortex-M4 firmware image (both for QEMU). Outputs go to a build
directory keyed by a hash of the sources and flags, so an edited source is rebuilt on the next use
and never reused stale.

Every build is warning-free with ``WARNINGS``: ``-std=c99 -Wall -Wextra -Wconversion -Wshadow
-Wcast-qual -Wundef -Wstrict-prototypes -pedantic -Werror``.

    python -m ecu.port.build       build everything this host can and print the paths
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

PORT_DIR = Path(__file__).resolve().parent


def _build_dir() -> Path:
    """$ECU_PORT_BUILD_DIR, else build/ next to the sources, else the user's cache (when the
    package is installed read-only)."""
    if os.environ.get("ECU_PORT_BUILD_DIR"):
        return Path(os.environ["ECU_PORT_BUILD_DIR"])
    if os.access(PORT_DIR, os.W_OK):
        return PORT_DIR / "build"
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "turbojet-sil" / "ecu-port"


BUILD_DIR = _build_dir()
WARNINGS = (
    "-std=c99",
    "-Wall",
    "-Wextra",
    "-Wconversion",
    "-Wshadow",
    "-Wcast-qual",
    "-Wundef",
    "-Wstrict-prototypes",
    "-pedantic",
    "-Werror",
)
# the control core, the frame codec, the CAN node (ecu_node.c: the C twin of ecu/node.py) and
# its XCP slave (ecu_xcp.c: the twin of ecu/xcp/slave.py)
CORE_SOURCES = ("ecu_core.c", "ecu_frames.c", "generated/turbojet.c", "ecu_node.c", "ecu_xcp.c")
HEADERS = (
    "ecu_core.h",
    "ecu_frames.h",
    "generated/turbojet.h",
    "generated/ecu_constants.h",
    "generated/ecu_xcp_map.h",
    "ecu_node.h",
    "ecu_xcp.h",
    "board.h",
    "ecu_main.h",
    "board_mps2.h",
)
ARM_CC = "arm-none-eabi-gcc"
ARM_CC_NOT_FOUND = f"{ARM_CC} not found (apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi)"
ARM_FLAGS = ("-mcpu=cortex-m4", "-mthumb", "-Os", "-ffunction-sections", "-fdata-sections")


class PortBuildError(RuntimeError):
    """The C port could not be built (no compiler, or the compiler refused the sources)."""


def host_compiler() -> str:
    """The host C compiler: $CC, else cc, gcc or clang on PATH."""
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return name
    raise PortBuildError(
        "no C compiler found for the C port of the ECU (looked for $CC, cc, gcc, clang); "
        "install one, e.g. apt-get install gcc"
    )


def _key(cc: str, flags: tuple[str, ...], sources: tuple[str, ...]) -> str:
    h = hashlib.sha256(" ".join((cc, *flags)).encode())
    for name in (*sources, *HEADERS):
        h.update(name.encode())
        h.update((PORT_DIR / name).read_bytes())
    for flag in flags:  # the linker script's text, as a source's
        if flag.startswith("-T"):
            h.update(Path(flag[2:]).read_bytes())
    return h.hexdigest()[:16]


def _compile(
    cc: str,
    flags: tuple[str, ...],
    sources: tuple[str, ...],
    out_name: str,
    libs: tuple[str, ...] = (),
) -> Path:
    """Compile ``sources`` into BUILD_DIR/<hash>/<out_name> unless that exists already
    (``libs``: linked after the sources)."""
    out = BUILD_DIR / _key(cc, (*flags, *libs), sources) / out_name
    if out.exists():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    print(f"ecu.port: compiling {out_name} with {cc} (once: kept in {out.parent})", file=sys.stderr)
    fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=f".{out_name}.")
    os.close(fd)
    cmd = [cc, *flags, f"-I{PORT_DIR}", *(str(PORT_DIR / s) for s in sources), *libs, "-o", tmp]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        Path(tmp).unlink(missing_ok=True)
        raise PortBuildError(f"{' '.join(cmd)} failed:\n{proc.stderr.strip()}")
    os.replace(tmp, out)  # atomic: concurrent builders never see a half-written file
    return out


def host_library(cc: str | None = None) -> Path:
    """The core, frame codec and CAN node as a shared library for ctypes (with field names)."""
    cc = cc or host_compiler()
    flags = (*WARNINGS, "-O2", "-fPIC", "-shared", "-DECU_WITH_NAMES")
    return _compile(cc, flags, CORE_SOURCES, "libecu_port.so")


def host_replayer(cc: str | None = None, *, sanitize: bool = False) -> Path:
    """The golden-vector replayer for the host: ``replay FILE`` (exit 0 when every tick matches);
    ``sanitize``: built with UBSan and ASan, stopping at the first undefined behaviour."""
    cc = cc or host_compiler()
    flags = (*WARNINGS, "-O2", "-DECU_WITH_NAMES")
    if sanitize:
        flags += ("-g", "-fsanitize=undefined,address", "-fno-sanitize-recover=all")
    return _compile(cc, flags, (*CORE_SOURCES, "replay.c"), "replay-san" if sanitize else "replay")


def _require_arm_cc() -> None:
    if not shutil.which(ARM_CC):
        raise PortBuildError(ARM_CC_NOT_FOUND)


def arm_replayer(systick: bool = False, stages: bool = False) -> Path:
    """The replayer for a Cortex-M4 (mps2-an386 under QEMU), reading vectors by semihosting;
    ``systick``: the variant that counts SysTick around each tick; ``stages``: around each of
    the tick's stages too (the core built with ECU_STAGE_PROFILE; see replay.c)."""
    _require_arm_cc()
    if stages:
        variant, name = ("-DREPLAY_SYSTICK", "-DECU_STAGE_PROFILE"), "replay-cm4-stages.elf"
    elif systick:
        variant, name = ("-DREPLAY_SYSTICK",), "replay-cm4-systick.elf"
    else:
        variant, name = (), "replay-cm4.elf"
    flags = (
        *WARNINGS,
        *ARM_FLAGS,
        *variant,
        "--specs=rdimon.specs",
        "-Wl,--gc-sections",
        f"-T{PORT_DIR / 'mps2_an386.ld'}",
    )
    sources = (*CORE_SOURCES, "replay.c", "startup_cm4.s")
    return _compile(ARM_CC, flags, sources, name)


PIL_SOURCES = ("ecu_main.c", "board_mps2.c", "startup_pil.s")
PIL_LINKS = {"eth": "board_mps2_eth.c", "slcan": "board_mps2_slcan.c"}  # the board's CAN link


def arm_pil_image(link: str = "eth") -> Path:
    """The firmware image for QEMU's mps2-an386 (ecu_main.c on board_mps2.c) with its CAN on
    ``link`` (PIL_LINKS: Ethernet or slcan on UART0): no C library start-up, no semihosting, no
    heap (a call that needs one would not link)."""
    if link not in PIL_LINKS:
        raise ValueError(f"unknown CAN link {link!r} (known: {', '.join(PIL_LINKS)})")
    _require_arm_cc()
    flags = (
        *WARNINGS,
        *ARM_FLAGS,
        "-DECU_NODE_PROFILE",
        "-nostartfiles",
        "--specs=nano.specs",
        "-Wl,--gc-sections",
        f"-T{PORT_DIR / 'mps2_an386_pil.ld'}",
    )
    sources = (*CORE_SOURCES, *PIL_SOURCES, PIL_LINKS[link])
    return _compile(ARM_CC, flags, sources, f"ecu-pil-{link}.elf", libs=("-lc", "-lgcc"))


def arm_objects() -> dict[str, Path]:
    """The control core, the frame codec and the CAN node, each compiled alone for the
    Cortex-M4 (for sizes): source name -> object."""
    _require_arm_cc()
    flags = (*WARNINGS, *ARM_FLAGS, "-c")
    return {s: _compile(ARM_CC, flags, (s,), Path(s).stem + ".o") for s in CORE_SOURCES}


# the code of the flash target: the control core, the frame codec and E2E; its public functions
# (declared in FLASH_HEADERS) are what firmware calls
FLASH_SOURCES = ("ecu_core.c", "ecu_frames.c", "generated/turbojet.c")
FLASH_HEADERS = ("ecu_core.h", "ecu_frames.h")


# the CAN node with its XCP slave, on the core and the frame code: what the node's flash figure
# links (sil bench port)
NODE_XCP_SOURCES = (*FLASH_SOURCES, "ecu_node.c", "ecu_xcp.c")
NODE_XCP_HEADERS = (*FLASH_HEADERS, "ecu_node.h", "ecu_xcp.h")


def public_functions(header: str) -> tuple[str, ...]:
    """The functions a header of the port declares, in order (its ``ecu_*`` prototypes), but
    those of its conditional parts (host builds' names, the integrator's profile hooks, the
    stage profile's hook)."""
    text = re.sub(r"/\*.*?\*/", "", (PORT_DIR / header).read_text(), flags=re.S)
    text = re.sub(
        r"^#ifdef (ECU_WITH_NAMES|ECU_NODE_PROFILE|ECU_STAGE_PROFILE)\b.*?^#endif",
        "",
        text,
        flags=re.M | re.S,
    )
    return tuple(re.findall(r"^[a-z][\w \t*]*?\b(ecu_\w+)\s*\(", text, re.M))


def arm_flash_image(
    sources: tuple[str, ...] = FLASH_SOURCES,
    headers: tuple[str, ...] = FLASH_HEADERS,
    name: str = "ecu-flash.elf",
) -> Path:
    """The control core, the frame codec and E2E as firmware links them, for their flash figure:
    the Cortex-M4 objects of ``sources`` (``arm_objects``: a section per function and per
    object) linked with -Wl,--gc-sections, libgcc and newlib-nano, with the public functions of
    ``headers`` as the only references from outside (-Wl,--undefined); with NODE_XCP_SOURCES and
    NODE_XCP_HEADERS, the same with the CAN node and its XCP slave. It holds what those
    functions need and nothing else: the generated per-signal helpers no code calls are dropped,
    as from any image linked with --gc-sections. Not for running (no vector table, no start-up
    code). The linker's map lies next to it (``.map``): where each byte comes from."""
    objects = arm_objects()
    roots = tuple(root for header in headers for root in public_functions(header))
    flags = (
        *ARM_FLAGS,
        "-nostartfiles",
        "--specs=nano.specs",
        "-Wl,--gc-sections",
        f"-Wl,--entry={roots[0]}",
        *(f"-Wl,--undefined={name}" for name in roots),
    )
    paths = [objects[s] for s in sources]
    h = hashlib.sha256(" ".join((ARM_CC, *flags)).encode())
    for path in paths:
        h.update(path.read_bytes())
    out = BUILD_DIR / h.hexdigest()[:16] / name
    if out.exists():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=f".{name}.")
    os.close(fd)
    cmd = [ARM_CC, *flags, *map(str, paths), "-lc", "-lgcc", f"-Wl,-Map={tmp}.map", "-o", tmp]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        Path(tmp).unlink(missing_ok=True)
        Path(f"{tmp}.map").unlink(missing_ok=True)
        raise PortBuildError(f"{' '.join(cmd)} failed:\n{proc.stderr.strip()}")
    os.replace(f"{tmp}.map", out.with_suffix(".map"))
    os.replace(tmp, out)  # last: the image stands for both
    return out


def main() -> int:
    print(f"host library: {host_library()}")
    print(f"host replayer: {host_replayer()}")
    try:
        print(f"Cortex-M4 replayer: {arm_replayer()}")
        for link in PIL_LINKS:
            print(f"Cortex-M4 firmware image (mps2-an386, CAN on {link}): {arm_pil_image(link)}")
    except PortBuildError as exc:
        print(f"Cortex-M4 builds: not built: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except PortBuildError as exc:
        print(f"ecu.port.build: {exc}", file=sys.stderr)
        sys.exit(2)
