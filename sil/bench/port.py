"""`sil bench port`: figures of the C port.

- flash and RAM on a Cortex-M4, against the targets of 16 KiB and 2.25 KiB. Flash is what firmware
  carries of the control core, the frame codec and E2E: ``arm-none-eabi-size`` of an image of
  their objects (-Os, a section per function) linked with --gc-sections from their public
  functions, with libgcc and the C library (``ecu.port.build.arm_flash_image``), split by origin
  through the linker's map; the objects' own sizes, unused functions included, are a detail line.
  RAM is the instance and the parameters as the replayer holds them, plus the stack bound: the
  deepest call chain from the core's entry points over GCC's call graph with its frames
  (``-fcallgraph-info=su``), any library helper's frames read from the image;
- instructions per tick: callgrind on the host build (``--toggle-collect=ecu_tick``) and QEMU on
  the Cortex-M4 build (``-icount shift=0``: SysTick counts the virtual clock, calibrated in the
  same run by a loop of known length), both replaying the MRAC golden vector; per stage of the
  tick on the Cortex-M4 (``cm4_stage_instructions_per_tick_<stage>``, the stages of
  ecu/firmware.py in their order): the same replay with the core built with ECU_STAGE_PROFILE,
  SysTick counted from each stage's end to the next's (the first from the call of ecu_tick),
  the profiling hook's own cost taken off each call; control law and limit selection run in
  RUN only, their figures are per tick of the whole vector;
- the CAN node with its XCP slave: flash (linked with the core and the frame code, split by
  origin; the whole image stated too) and RAM (its instances and the deepest stack from its entry
  points) against 20 KiB and 3 KiB, the slave's ODT entries (>= 16), and in the loop (the
  firmware image on QEMU -icount, lockstep on the fast plant) the node's instructions per tick
  without the slave, with it and no master (its share against 10 %) and with a master's DAQ list
  of 20 measurements;
- microseconds per tick called from Python (the C core through ctypes, the Python firmware);
- the SIL in process on the aero-thermal MRAC scenario (real-time factors): with the C ECU in
  the compiled loop (sil/run/compiled_loop.py) and, for the ratio, in the Python loop it replaces,
  and with the Python ECU; where the compiled run's time goes (cProfile), and the bound the
  plant alone sets (its CPU time per ECU period).
"""

from __future__ import annotations

import cProfile
import dataclasses
import pstats
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

from ecu import golden
from ecu.port import build, qemu
from ecu.port.core import CEcu
from sil.run import golden as golden_sources

SCENARIO = "thesis-5.3-mrac-aero"
VECTOR = "mrac-aero"
FLASH_TARGET = 16 * 1024
RAM_TARGET = 2304  # 2.25 KiB: the core with the engine's logbook in its state
INSTRUCTIONS_TARGET = 5000
REPEATS = 3  # SIL runs per case
SIL_TARGET = 500.0  # in process with the C ECU, real-time factor
NODE_FLASH_TARGET = 20 * 1024  # the CAN node with its XCP slave
NODE_RAM_TARGET = 3 * 1024
ODT_ENTRIES_TARGET = 16
XCP_SHARE_TARGET = 10.0  # % of the node's instructions per tick, no master attached
PIL_TICKS = 300
TARGET_TEXT = {
    "flash": "control core and frame codec <= 16 KiB of Cortex-M4 flash",
    "ram": "<= 2.25 KiB of RAM with the CAN node (data, bss, stack bound)",
    "instructions": "< 5,000 instructions per tick (host and Cortex-M4)",
    "sil_inproc": ">= 500x real time in process with the C ECU",
    "node_xcp_flash": "the CAN node with its XCP slave <= 20 KiB of Cortex-M4 flash",
    "node_xcp_ram": "the CAN node with its XCP slave <= 3 KiB of RAM (data, bss, stack bound), "
    "with >= 16 ODT entries",
    "xcp_share": "the XCP slave <= 10 % of the node's instructions per tick in the loop, no master",
}


def _size(obj: Path) -> tuple[int, int, int]:
    """text, data, bss of an object file."""
    out = subprocess.run(
        ["arm-none-eabi-size", str(obj)], capture_output=True, text=True, check=True
    ).stdout
    text, data, bss = (int(x) for x in out.splitlines()[1].split()[:3])
    return text, data, bss


def _symbol_sizes(elf: Path, names: tuple[str, ...]) -> dict[str, int]:
    out = subprocess.run(
        ["arm-none-eabi-nm", "-S", str(elf)], capture_output=True, text=True, check=True
    ).stdout
    sizes: dict[str, int] = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 4 and parts[3] in names:
            sizes[parts[3]] = sizes.get(parts[3], 0) + int(parts[1], 16)
    return sizes


ROOTS = ("ecu_tick", "ecu_init", "ecu_params_load", "ecu_state_digest")  # the core's entries
_FRAME = re.compile(
    r"\t(?:push|stmdb)(?:\.w)?\s+(?:sp!,\s*)?\{([^}]*)\}"  # push {r4, lr}: 4 bytes a register
    r"|\[sp, #-(\d+)\]!"  # strd ip, lr, [sp, #-16]!
    r"|\tsub(?:\.w)?\s+sp, (?:sp, )?#(\d+)"  # sub sp, #24
)
_CALL = re.compile(r"\tbl\s+[0-9a-f]+ <([^>+]+)>")


def _library_frames(image: Path, name: str, seen: tuple[str, ...] = ()) -> int:
    """The deepest stack a library function of the linked image takes, with what it calls: its
    frame read from its machine code (pushes, pre-decrements and sp subtractions) plus its
    deepest callee's."""
    text = subprocess.run(
        ["arm-none-eabi-objdump", "-d", f"--disassemble={name}", str(image)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    frame = 0
    for m in _FRAME.finditer(text):
        regs, pre, sub = m.groups()
        frame += 4 * len(regs.split(",")) if regs else int(pre or sub)
    callees = {c for c in _CALL.findall(text) if c != name and c not in seen}
    return frame + max((_library_frames(image, c, (*seen, name)) for c in callees), default=0)


def _stack_bound(image: Path) -> int:
    """The deepest stack the core's entry points take at -Os: over GCC's call graph of
    ecu_core.c (-fcallgraph-info=su: each function's static frame and its calls), the deepest
    chain from ROOTS, with the frames of any library helpers it calls read from the linked
    image. The core has no recursion and no dynamic frames."""
    with tempfile.TemporaryDirectory() as tmp:
        obj = Path(tmp) / "ecu_core.o"
        subprocess.run(
            [
                build.ARM_CC,
                *build.WARNINGS,
                *build.ARM_FLAGS,
                "-fstack-usage",
                "-fcallgraph-info=su",
                "-c",
                str(build.PORT_DIR / "ecu_core.c"),
                "-o",
                str(obj),
            ],  # fmt: skip
            check=True,
            capture_output=True,
            cwd=tmp,
        )
        graph = obj.with_suffix(".ci").read_text()
    frames: dict[str, int] = {}
    for title, label in re.findall(r'node: \{ title: "([^"]+)" label: "([^"]*)"', graph):
        own = re.search(r"\\n(\d+) bytes \((static|dynamic[^)]*)\)", label)
        if own is not None and own.group(2) != "static":
            raise RuntimeError(f"{title}: a dynamic stack frame has no static bound")
        frames[title] = int(own.group(1)) if own else -1  # -1: not ours (a library helper)
    calls: dict[str, set[str]] = {}
    for src, dst in re.findall(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"', graph):
        calls.setdefault(src, set()).add(dst)

    def deepest(node: str, path: tuple[str, ...]) -> int:
        if node in path:
            raise RuntimeError(f"recursion through {node}: no static stack bound")
        own = frames.get(node, -1)
        if own < 0:
            return _library_frames(image, node.rsplit(":", 1)[-1])
        return own + max((deepest(c, (*path, node)) for c in calls.get(node, ())), default=0)

    roots = [t for t in frames if t.rsplit(":", 1)[-1] in ROOTS]
    return max(deepest(r, ()) for r in roots)


def _call_graph_depth(image: Path, sources: tuple[str, ...], roots: tuple[str, ...]) -> int:
    """The deepest stack from ``roots`` over GCC's call graphs of ``sources``
    (-fcallgraph-info=su, as _stack_bound for the core), with the library helpers' frames read
    from the linked ``image``. Calls through the integrator's callbacks (function pointers) are
    not in the graph: their frames come on top."""
    frames: dict[str, int] = {}
    calls: dict[str, set[str]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for k, source in enumerate(sources):
            obj = Path(tmp) / f"{k}.o"
            subprocess.run(
                [build.ARM_CC, *build.WARNINGS, *build.ARM_FLAGS, f"-I{build.PORT_DIR}",
                 "-fstack-usage", "-fcallgraph-info=su", "-c", str(build.PORT_DIR / source),
                 "-o", str(obj)],
                check=True, capture_output=True, cwd=tmp,
            )  # fmt: skip
            graph = obj.with_suffix(".ci").read_text()
            for title, label in re.findall(r'node: \{ title: "([^"]+)" label: "([^"]*)"', graph):
                own = re.search(r"\\n(\d+) bytes \((static|dynamic[^)]*)\)", label)
                if own is not None and own.group(2) != "static":
                    raise RuntimeError(f"{title}: a dynamic stack frame has no static bound")
                if own is not None:
                    frames[title] = int(own.group(1))
            pairs = re.findall(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"', graph)
            for src, dst in pairs:
                calls.setdefault(src, set()).add(dst)

    def deepest(node: str, path: tuple[str, ...]) -> int:
        if node in path:
            raise RuntimeError(f"recursion through {node}: no static stack bound")
        if node not in frames:
            return _library_frames(image, node.rsplit(":", 1)[-1])
        return frames[node] + max((deepest(c, (*path, node)) for c in calls.get(node, ())),
                                  default=0)  # fmt: skip

    return max(deepest(r, ()) for r in roots)


def _flash_sections(elf: Path) -> set[str]:
    """The sections of an image that take flash: allocated with contents (code, constants, the
    initial values of .data)."""
    out = subprocess.run(
        ["arm-none-eabi-objdump", "-h", str(elf)], capture_output=True, text=True, check=True
    ).stdout
    found = re.findall(r"^\s*\d+\s+(\S+)\s+[0-9a-f]+\s.*\n\s+(.*)$", out, re.M)
    return {name for name, flags in found if "ALLOC" in flags and "LOAD" in flags}


def linked_bytes(elf: Path) -> dict[str, int]:
    """Flash bytes of a linked image by where they come from, from the linker's map next to it:
    an object by file name, ``libgcc``, ``libc``; alignment fill counts with the input section
    before it. The values add up to the image's text + data."""
    sections = _flash_sections(elf)
    text = elf.with_suffix(".map").read_text()
    text = text[text.index("Linker script and memory map") :]
    entry = re.compile(
        r"^(?P<out>\.\S+)\s+0x[0-9a-f]+\s+0x[0-9a-f]+"  # an output section
        r"|^ (?P<name>[.*]\S*)\s+0x[0-9a-f]+\s+0x(?P<size>[0-9a-f]+)[ \t]*(?P<file>\S*)",
        re.M,
    )  # an input section (name and address may be on two lines) or *fill*
    counts: dict[str, int] = {}
    current, origin = "", ""
    for m in entry.finditer(text):
        if m["out"]:
            current, origin = m["out"], ""
            continue
        if current not in sections or not int(m["size"], 16):
            continue
        if m["name"] != "*fill*":
            archive = re.search(r"lib(gcc|c|c_nano)\.a\(", m["file"])
            origin = (
                {"gcc": "libgcc", "c_nano": "libc"}.get(archive[1], archive[1])
                if archive
                else (Path(m["file"]).name)
            )
        counts[origin or "fill"] = counts.get(origin or "fill", 0) + int(m["size"], 16)
    return counts


def arm_figures(elf: Path) -> dict:
    """Flash and RAM on the Cortex-M4 (``elf``: the replayer, which holds the instance and the
    parameters as firmware would)."""
    objects = build.arm_objects()
    _, core_data, core_bss = _size(objects["ecu_core.c"])
    image = build.arm_flash_image()
    flash = sum(_size(image)[:2])
    parts = linked_bytes(image)
    frames = parts.get("ecu_frames.o", 0) + parts.get("turbojet.o", 0)
    libgcc = _symbol_sizes(elf, ("__aeabi_ldivmod", "__udivmoddi4", "__aeabi_uldivmod"))
    unlinked = {Path(s).stem + ".o": sum(_size(objects[s])[:2]) for s in build.FLASH_SOURCES}
    unlinked_total = sum(unlinked.values()) + sum(libgcc.values())
    division = f" + libgcc 64-bit division {parts['libgcc']}" if parts.get("libgcc") else ""
    node = sum(_size(objects["ecu_node.c"])[:2])  # the CAN node (not in the flash target)
    ram = _symbol_sizes(elf, ("ecu", "params"))
    stack = _stack_bound(image)
    ram_total = sum(ram.values()) + core_data + core_bss + stack
    return {
        # linked with --gc-sections from the public functions: what firmware carries
        "cm4_flash_bytes": flash,
        "cm4_core_flash_bytes": flash - frames,
        "cm4_core_flash_detail": f"ecu_core.o {parts.get('ecu_core.o', 0)}{division}"
        f" + memcpy, memset {parts.get('libc', 0)}"
        + (f" + alignment {parts['fill']}" if parts.get("fill") else ""),
        "cm4_frames_flash_bytes": frames,
        "cm4_frames_flash_detail": f"ecu_frames.o {parts.get('ecu_frames.o', 0)} "
        f"+ turbojet.o {parts.get('turbojet.o', 0)}",
        # every function of the objects, before the linker drops the unused ones
        "cm4_flash_objects_detail": " + ".join(f"{k} {v}" for k, v in unlinked.items())
        + (f" + libgcc 64-bit division {sum(libgcc.values())}" if libgcc else "")
        + f" = {unlinked_total}",
        "cm4_node_flash_bytes": node,
        "cm4_ram_bytes": ram_total,
        "cm4_ram_detail": f"ecu_t {ram.get('ecu', 0)} + params {ram.get('params', 0)} "
        f"+ stack bound {stack}",
        "flash_target_met": flash <= FLASH_TARGET,
        "ram_target_met": ram_total <= RAM_TARGET,
    }


def _type_sizes(names: tuple[str, ...]) -> dict[str, int]:
    """sizeof of the port's types on the Cortex-M4 (objects of their size, read by nm)."""
    with tempfile.TemporaryDirectory() as tmp:
        source = Path(tmp) / "sizes.c"
        source.write_text(
            '#include "ecu_node.h"\n' + "".join(f"char size_of_{n}[sizeof({n})];\n" for n in names)
        )
        obj = Path(tmp) / "sizes.o"
        subprocess.run(
            [build.ARM_CC, *build.ARM_FLAGS, f"-I{build.PORT_DIR}", "-c", str(source), "-o",
             str(obj)],
            check=True, capture_output=True,
        )  # fmt: skip
        found = _symbol_sizes(obj, tuple(f"size_of_{n}" for n in names))
    return {n: found[f"size_of_{n}"] for n in names}


NODE_ROOTS = ("ecu_node_frame", "ecu_node_receive", "ecu_node_timeout", "ecu_node_period",
              "ecu_node_init", "ecu_xcp_init")  # fmt: skip


def node_xcp_figures() -> dict:
    """Flash and RAM of the CAN node with its XCP slave on the Cortex-M4: the image of the core,
    the frame code, the node and the slave linked from their public functions
    (``build.arm_flash_image`` with NODE_XCP_SOURCES), split by origin; RAM: the ecu_node_t and
    ecu_xcp_t instances (the slave's queue, block and DAQ tables among them) and the deepest
    stack from the node's entry points (the core's tick and the slave's serving and sampling
    in it). The core's own figures (its flash, ecu_t and parameters) are arm_figures'; the
    whole image is stated beside."""
    from ecu.port.xcp import c_limits

    image = build.arm_flash_image(build.NODE_XCP_SOURCES, build.NODE_XCP_HEADERS,
                                  "ecu-node-xcp.elf")  # fmt: skip
    parts = linked_bytes(image)
    total = sum(_size(image)[:2])
    node, slave = parts.get("ecu_node.o", 0), parts.get("ecu_xcp.o", 0)
    sizes = _type_sizes(("ecu_node_t", "ecu_xcp_t", "ecu_t", "ecu_params_t"))
    stack = _call_graph_depth(image, build.NODE_XCP_SOURCES, NODE_ROOTS)
    objects = build.arm_objects()
    static = sum(sum(_size(objects[s])[1:]) for s in ("ecu_node.c", "ecu_xcp.c"))
    ram = sizes["ecu_node_t"] + sizes["ecu_xcp_t"] + stack + static
    entries = c_limits().max_entries
    return {
        "cm4_node_xcp_flash_bytes": node + slave,
        "cm4_node_xcp_flash_detail": f"ecu_node.o {node} + ecu_xcp.o {slave}",
        "cm4_image_flash_bytes": total,
        "cm4_image_flash_detail": " + ".join(f"{k} {v}" for k, v in parts.items()),
        "cm4_node_xcp_ram_bytes": ram,
        "cm4_node_xcp_ram_detail": f"ecu_node_t {sizes['ecu_node_t']} + ecu_xcp_t "
        f"{sizes['ecu_xcp_t']} + stack bound {stack} (the tick's within it)"
        + (f" + static {static}" if static else ""),
        "cm4_image_ram_bytes": ram + sizes["ecu_t"] + sizes["ecu_params_t"],
        "xcp_odt_entries": entries,
        "xcp_limits": str(c_limits()),
        "node_xcp_flash_target_met": node + slave <= NODE_FLASH_TARGET,
        "node_xcp_ram_target_met": ram <= NODE_RAM_TARGET and entries >= ODT_ENTRIES_TARGET,
    }


def _daq_frames(names: tuple[str, ...]) -> list[bytes]:
    """A DAQ list of these measurements on the control tick, packed as pyXCP packs it (ODTs of
    at most 7 bytes, 3 in the first beside the timestamp), as command frames."""
    import struct

    from ecu.xcp import codes as C
    from ecu.xcp import memory as MEM

    odts: list[list[tuple[int, int]]] = [[]]
    room = 3
    for name in names:
        k = MEM.MEAS_INDEX[name]
        size = MEM.MEASUREMENTS[k].size
        if size > room:
            odts.append([])
            room = 7
        odts[-1].append((MEM.measurement_address(k), size))
        room -= size
    frames = [bytes((C.Cmd.FREE_DAQ,)), bytes((C.Cmd.ALLOC_DAQ, 0, 1, 0)),
              bytes((C.Cmd.ALLOC_ODT, 0, 0, 0, len(odts)))]  # fmt: skip
    frames += [bytes((C.Cmd.ALLOC_ODT_ENTRY, 0, 0, 0, j, len(o))) for j, o in enumerate(odts)]
    for j, odt in enumerate(odts):
        if odt:
            frames.append(bytes((C.Cmd.SET_DAQ_PTR, 0, 0, 0, j, 0)))
            frames += [struct.pack("<BBBBI", C.Cmd.WRITE_DAQ, 0xFF, n, 0, a) for a, n in odt]
    frames.append(struct.pack("<BBHHBB", C.Cmd.SET_DAQ_LIST_MODE, 0x10, 0, 0, 1, 0))
    return [*frames, bytes((C.Cmd.START_STOP_DAQ_LIST, 1, 0, 0))]


DAQ_NAMES = (
    "ticks", "mode", "fault_word", "speed_rpm", "speed_ref", "egt", "pump_voltage", "pump_duty",
    "pump_enable", "supply", "pump_current", "pump_health", "owner", "inputs_valid", "ap21",
    "ap22", "lambda", "theta21", "kx1", "kr",
)  # fmt: skip


def pil_node_instructions(xcp: bool, daq: bool = False, ticks: int = PIL_TICKS) -> dict:
    """The image in the loop in lockstep (QEMU -icount, its per-tick profile), closed on the
    fast plant from rest (the start, then idle): instructions per tick of the node call that
    runs a tick (its frames, the slave's serving and sampling, the core) and of the core alone;
    ``xcp``: the slave on the node; ``daq``: a master with a DAQ list of 20 measurements on the
    control tick, set up before the plant's first frame."""
    import can

    from ecu.params import EcuParams
    from ecu.port.pil import PilImage, XcpBlock, calibration_block
    from ecu.port.xcp_run import run_record
    from ecu.service.port import boot
    from ecu.xcp import codes as C
    from ecu.xcp.seed_key import key_for
    from plant.fast_plant import FastPlant
    from plant.interface import PlantConfig
    from plant.node import PlantNode

    booted = boot(EcuParams(), None)
    block = calibration_block(
        booted.table.firmware, lockstep=True,
        xcp=XcpBlock((0x700, 0x701), 7, run_record(booted.table)) if xcp else None,
    )  # fmt: skip
    plant = PlantNode(FastPlant(PlantConfig(ecu_period_s=0.01)))
    frames: list[tuple[int, bytes]] = []
    plant.start(lambda i, d: frames.append((i, bytes(d))))
    with PilImage(block, link="eth") as image:
        bus = image.open_bus()
        try:
            image.wait_ready()

            def request(data: bytes) -> bytes:
                bus.send(can.Message(arbitration_id=0x700, is_extended_id=False, data=data))
                msg = bus.recv(5.0)
                if msg is None:
                    raise RuntimeError(f"the image did not answer XCP {data.hex()}")
                return bytes(msg.data)

            if daq:
                request(bytes((C.Cmd.CONNECT, 0)))
                seed = request(bytes((C.Cmd.GET_SEED, 0, C.RES_DAQ)))[2:6]
                request(bytes((C.Cmd.UNLOCK, 2)) + key_for(seed))
                for frame in _daq_frames(DAQ_NAMES):
                    if request(frame)[0] != C.PID_RES:
                        raise RuntimeError(f"the image refused the DAQ set-up at {frame.hex()}")
            for _ in range(ticks):
                for frame_id, data in frames:
                    bus.send(can.Message(arbitration_id=frame_id, is_extended_id=False, data=data))
                frames.clear()
                while (msg := bus.recv(5.0)) is not None:
                    if msg.arbitration_id != 0x701:
                        plant.on_frame(msg.arbitration_id, bytes(msg.data),
                                       lambda i, d: frames.append((i, bytes(d))))  # fmt: skip
                    if msg.arbitration_id == 0x110:  # EcuActuator closes the tick
                        break
                else:
                    raise RuntimeError("the image stopped answering its ticks")
        finally:
            bus.shutdown()
    return image.profile.summary()["instructions_per_tick"]


def xcp_instruction_figures(ticks: int = PIL_TICKS) -> dict:
    """What the XCP slave costs in the loop: the node's instructions per tick without it, with
    it and no master, and with a master's DAQ list of 20 measurements."""
    without = pil_node_instructions(False, ticks=ticks)
    idle = pil_node_instructions(True, ticks=ticks)
    measured = pil_node_instructions(True, daq=True, ticks=ticks)
    share = 100.0 * (idle["node_mean"] - without["node_mean"]) / without["node_mean"]
    return {
        "pil_node_instructions_per_tick_without_xcp": without["node_mean"],
        "pil_node_instructions_per_tick_xcp_no_master": idle["node_mean"],
        "pil_node_instructions_per_tick_xcp_daq_20": measured["node_mean"],
        "pil_core_instructions_per_tick": without["core_mean"],
        "xcp_share_no_master_pct": round(share, 2),
        "xcp_share_target_met": share <= XCP_SHARE_TARGET,
    }


def callgrind_instructions(replayer: Path, vectors: Path, ticks: int) -> float | str:
    if not shutil.which("valgrind"):
        return "valgrind not found (apt-get install valgrind)"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "callgrind.out"
        subprocess.run(
            [
                "valgrind",
                "--tool=callgrind",
                "--toggle-collect=ecu_tick",
                f"--callgrind-out-file={out}",
                str(replayer),
                str(vectors),
            ],  # fmt: skip
            check=True,
            capture_output=True,
        )
        total = re.search(r"^(?:summary|totals): (\d+)", out.read_text(), re.M)
    return round(int(total.group(1)) / ticks, 1) if total else "no totals in callgrind output"


def qemu_instructions(vectors: Path, ticks: int) -> float | str:
    try:
        elf = build.arm_replayer(systick=True)
        done = qemu.run(elf, vectors, icount=True)
    except (build.PortBuildError, FileNotFoundError) as exc:
        return str(exc)
    found = re.search(r"SYSTICK (\d+) (\d+) (\d+)", done.stdout)
    if done.returncode != 0 or not found:
        return f"QEMU replay failed: {done.stdout.strip()} {done.stderr.strip()}"
    counts, cal_counts, cal_instructions = (int(x) for x in found.groups())
    return round(counts * cal_instructions / cal_counts / ticks, 1)


STAGES = (
    "sensors", "history", "trips", "start_sequencer", "mode", "control_law", "limit_selection",
    "pump_driver", "actuator_tests", "health", "logbook",
)  # fmt: skip


def qemu_stage_instructions(vectors: Path, ticks: int) -> dict:
    """Instructions per tick of each of the tick's STAGES on the Cortex-M4 (QEMU -icount, the
    replayer built with the stage profile): ``cm4_stage_instructions_per_tick_<stage>``."""
    key = "cm4_stage_instructions_per_tick"
    try:
        elf = build.arm_replayer(stages=True)
        done = qemu.run(elf, vectors, icount=True)
    except (build.PortBuildError, FileNotFoundError) as exc:
        return {key: str(exc)}
    systick = re.search(r"SYSTICK (\d+) (\d+) (\d+)", done.stdout)
    stages = re.search(r"STAGES ([\d ]+)", done.stdout)
    words = [int(x) for x in stages.group(1).split()] if stages else []
    if done.returncode != 0 or not systick or len(words) != 2 + 2 * len(STAGES):
        return {key: f"QEMU stage replay failed: {done.stdout.strip()} {done.stderr.strip()}"}
    _, cal_counts, cal_instructions = (int(x) for x in systick.groups())
    per_count = cal_instructions / cal_counts
    hook = words[0] / words[1]  # counts of one call of the hook
    return {
        f"{key}_{name}": round((counts - calls * hook) * per_count / ticks, 1)
        for name, counts, calls in zip(STAGES, words[2::2], words[3::2], strict=True)
    }


def tick_us(g: golden.Golden) -> dict:
    """Microseconds per tick called from Python: the C core through ctypes and the Python
    firmware, on the vector's inputs."""
    from ecu.firmware import Ecu, EcuInputs

    n_in = len(golden.INPUT_FIELDS)
    inputs = []
    for t in range(g.ticks):
        i = EcuInputs()
        row = g.rows[t * golden.ROW_WORDS : t * golden.ROW_WORDS + n_in]
        for name, value in zip(golden.INPUT_FIELDS, row, strict=True):
            setattr(i, name, value)
        inputs.append(i)
    figures = {}
    for key, ecu in (("ctypes_c_tick_us", CEcu(g.params)), ("python_tick_us", Ecu(g.params))):
        t0 = time.perf_counter()
        for i in inputs:
            ecu.tick(i)
        figures[key] = round((time.perf_counter() - t0) / g.ticks * 1e6, 2)
    return figures


def plant_bound(s, ticks: int = 3000) -> dict:  # noqa: ANN001 (a sil.scenario.Scenario)
    """CPU time of the plant alone per ECU period, and the real-time factor it allows at most."""
    from sil.run import runner

    plant = runner.build_plant(s, s.seed)
    for _ in range(100):  # compiled, settled
        plant.step(0.5, True)
    cpu = time.process_time()
    for k in range(ticks):
        plant.step(0.5 + 0.02 * ((k // 500) % 2), True)
    per_tick = (time.process_time() - cpu) / ticks
    return {
        "plant_cpu_us_per_ecu_tick": round(per_tick * 1e6, 1),
        "plant_alone_max_realtime_factor": round(1.0 / s.ecu_rate_hz / per_tick, 1),
    }


def sil_figures(quick: bool) -> dict:
    """The in-process SIL with the C ECU (the compiled loop, and the Python loop it replaces),
    and with the Python ECU: best real-time factors of alternated runs; where the compiled run's
    wall time goes."""
    from sil import scenario
    from sil.run.runner import RunOptions
    from sil.run.runner import run as run_scenario

    s = scenario.load(SCENARIO)
    if quick:
        s = dataclasses.replace(s, duration_s=30.0)
    figures: dict = {"sil_scenario": s.name, "sil_sim_time_s": s.duration_s, **plant_bound(s)}
    cases = {  # key suffix: (ECU, compiled loop)
        "c_ecu": ("c", True),
        "c_ecu_python_loop": ("c", False),
        "python_ecu": ("python", False),
    }

    def options(duration: float, out: Path, impl: str, compiled: bool) -> RunOptions:
        cut = dataclasses.replace(s, duration_s=duration)
        return RunOptions(
            cut, out, mode="inproc", plots=False, progress=False, ecu_impl=impl,
            compiled_loop=compiled,
        )  # fmt: skip

    with tempfile.TemporaryDirectory() as tmp:
        for impl, compiled in cases.values():  # plant JIT, imports, the C build, the loop's JIT
            run_scenario(options(1.0, Path(tmp) / "warm", impl, compiled))
        best = dict.fromkeys(cases, 0.0)
        best_cpu = dict(best)
        for _ in range(REPEATS):  # alternated, best of each: the machine is shared
            for key, (impl, compiled) in cases.items():
                cpu = time.process_time()
                summary = run_scenario(options(s.duration_s, Path(tmp) / key, impl, compiled))
                cpu = time.process_time() - cpu
                best[key] = max(best[key], summary["realtime_factor"])
                best_cpu[key] = max(best_cpu[key], s.duration_s / cpu)
        for key in cases:
            figures[f"sil_inproc_realtime_factor_{key}"] = round(best[key], 1)
            # simulated time per CPU second of this process: what other processes' load spares
            figures[f"sil_inproc_cpu_realtime_factor_{key}"] = round(best_cpu[key], 1)
        figures["sil_inproc_target_met"] = best["c_ecu"] >= SIL_TARGET
        profile = cProfile.Profile()
        profile.runcall(run_scenario, options(s.duration_s, Path(tmp) / "profile", "c", True))
    stats = pstats.Stats(profile).stats  # type: ignore[attr-defined]
    total = sum(v[2] for v in stats.values()) or 1.0  # (the run's wall time, as profiled)
    # cumulative share of the run's parts (nested calls counted in their caller)
    parts = {
        "compiled_loop": ("sil/run/compiled_loop.py", "run_frames"),  # nodes, frames, recording
        "hand_over": ("sil/run/compiled_loop.py", "_hand_over"),  # frames to the recorder process
        "plan": ("sil/run/compiled_loop.py", "_plan"),  # the command node's frames, packed
        "recorder_close": ("sil/run/recorder_process.py", "close"),  # waiting for its last chunk
        "summary": ("sil/run/summary.py", "finish"),  # trace read back, metrics, summary.json
    }
    for key, (path, function) in parts.items():
        cumulative = sum(
            v[3] for (f, _, name), v in stats.items() if f.endswith(path) and name == function
        )
        figures[f"sil_c_ecu_cumulative_pct_{key}"] = round(100.0 * cumulative / total, 1)
    return figures


def run(quick: bool = False) -> dict:
    figures: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        g = golden_sources.record(VECTOR)
        vectors = Path(tmp) / f"{VECTOR}.gv"
        golden.write(g, vectors)
        figures["vector"] = f"{VECTOR} ({g.ticks} ticks)"
        try:
            figures.update(arm_figures(build.arm_replayer()))
            figures.update(node_xcp_figures())
        except (build.PortBuildError, FileNotFoundError, subprocess.CalledProcessError) as exc:
            figures["cm4"] = f"not measured: {exc}"
        try:
            figures.update(xcp_instruction_figures(100 if quick else PIL_TICKS))
        except Exception as exc:  # (QEMU missing, the image stopped: said, not raised)
            figures["pil_xcp"] = f"not measured: {exc}"
        replayer = build.host_replayer()
        figures["host_instructions_per_tick"] = callgrind_instructions(replayer, vectors, g.ticks)
        figures["cm4_qemu_instructions_per_tick"] = qemu_instructions(vectors, g.ticks)
        figures.update(qemu_stage_instructions(vectors, g.ticks))
        figures.update(tick_us(g))
    figures["instructions_target_met"] = all(
        isinstance(v, float) and v < INSTRUCTIONS_TARGET
        for v in (figures["host_instructions_per_tick"], figures["cm4_qemu_instructions_per_tick"])
    )
    figures.update(sil_figures(quick))
    return figures
