"""The Cortex-M4 build (arm-none-eabi-gcc -mcpu=cortex-m4 -mthumb -Os) replays the golden
vectors under qemu-system-arm (mps2-an386, semihosting), and its figures meet the targets."""

import ast
import re
import subprocess

import pytest

from ecu import firmware
from ecu.compiled_tick import source_file
from ecu.port import build, qemu
from sil.bench import port as bench
from sil.run import golden as sources


@pytest.fixture(scope="module")
def elf(toolchains):
    return build.arm_replayer()


@pytest.mark.parametrize("name", list(sources.SOURCES))
def test_cortex_m4_matches_every_tick(elf, vectors, name):
    path, g = vectors[name]
    done = qemu.run(elf, path, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.strip() == f"OK {g.ticks} ticks"


def test_cortex_m4_reports_a_difference(elf, vectors, tmp_path):
    path, _ = vectors["mrac-aero"]
    data = bytearray(path.read_bytes())
    data[-4] ^= 0x10  # the last tick's state digest
    bad = tmp_path / "bad.gv"
    bad.write_bytes(bytes(data))
    done = qemu.run(elf, bad, timeout=120)
    assert done.returncode != 0 and "state digest" in done.stdout


def test_flash_image_holds_the_public_functions_and_only_what_they_need(toolchains):
    """The flash figure's image: every public function of the core and the frame codec, the
    generated code they call, none of the generated helpers nobody calls; its bytes add up by
    origin."""
    image = build.arm_flash_image()
    symbols = subprocess.run(
        ["arm-none-eabi-nm", str(image)], capture_output=True, text=True, check=True
    ).stdout.split()
    roots = [*build.public_functions("ecu_core.h"), *build.public_functions("ecu_frames.h")]
    assert {"ecu_params_load", "ecu_init", "ecu_tick", "ecu_state_digest"} <= set(roots)
    assert {"ecu_frames_receive", "ecu_frames_telemetry", "ecu_e2e_crc"} <= set(roots)
    assert set(roots) <= set(symbols)
    assert "turbojet_ecu_telemetry_pack" in symbols
    assert not [s for s in symbols if s.endswith("_is_in_phys_range")]
    parts = bench.linked_bytes(image)
    assert set(parts) <= {"ecu_core.o", "ecu_frames.o", "turbojet.o", "libgcc", "libc", "fill"}
    assert sum(parts.values()) == sum(bench._size(image)[:2])


def test_flash_ram_and_instructions_per_tick_meet_the_targets(elf, vectors):
    figures = bench.arm_figures(elf)
    flash = figures["cm4_flash_bytes"]
    assert flash == figures["cm4_core_flash_bytes"] + figures["cm4_frames_flash_bytes"]
    assert flash <= 16 * 1024
    assert 0 < figures["cm4_ram_bytes"] <= bench.RAM_TARGET
    path, g = vectors["mrac-aero"]
    host = bench.callgrind_instructions(build.host_replayer(), path, g.ticks)
    arm = bench.qemu_instructions(path, g.ticks)
    assert isinstance(host, float) and isinstance(arm, float), (host, arm)
    assert 200 < host < 5000 and 200 < arm < 5000


def test_the_node_with_its_xcp_slave_meets_its_flash_and_ram_budgets(toolchains):
    """The CAN node with the XCP slave: <= 20 KiB of flash as linked with the core and the frame
    code, <= 3 KiB of RAM (its instances and the deepest stack from its entry points, the tick's
    within it), with at least 16 ODT entries; the whole image's bytes add up by origin."""
    figures = bench.node_xcp_figures()
    assert 0 < figures["cm4_node_xcp_flash_bytes"] <= 20 * 1024, figures
    assert 0 < figures["cm4_node_xcp_ram_bytes"] <= 3 * 1024, figures
    assert figures["xcp_odt_entries"] >= 16
    assert figures["node_xcp_flash_target_met"] and figures["node_xcp_ram_target_met"]
    parts = figures["cm4_image_flash_detail"].split(" + ")
    assert sum(int(p.rsplit(" ", 1)[1]) for p in parts) == figures["cm4_image_flash_bytes"]


def test_the_xcp_slave_costs_under_a_tenth_of_the_tick_in_the_loop(toolchains):
    """The image in the loop (QEMU -icount): the node's instructions per tick with the slave and
    no master within 10 % of those without it; a master's DAQ list of 20 measurements costs
    more, and the core's own instructions are the same."""
    figures = bench.xcp_instruction_figures(ticks=150)
    assert figures["xcp_share_target_met"], figures
    assert 0 <= figures["xcp_share_no_master_pct"] <= 10.0
    daq = figures["pil_node_instructions_per_tick_xcp_daq_20"]
    assert daq > figures["pil_node_instructions_per_tick_xcp_no_master"]


def test_the_stage_figures_cover_every_stage_and_add_up_to_the_tick(elf, vectors):
    """`sil bench port` lists instructions per tick for each stage of the tick, in the Python
    tick's order with its names (the C core's stage numbers the same), and on the Cortex-M4
    they account for the whole tick's count."""
    source = source_file(firmware).read_text()  # (the tick's source, also when it runs compiled)
    tick = next(node for node in ast.walk(ast.parse(source)) if isinstance(node, ast.ClassDef)
                and node.name == "Ecu").body  # fmt: skip
    body = next(f for f in tick if isinstance(f, ast.FunctionDef) and f.name == "tick")
    python_stages = tuple(re.findall(r"self\._stage_(\w+)\(", ast.get_source_segment(source, body)))
    header = (build.PORT_DIR / "ecu_core.h").read_text()
    c_stages = re.findall(r"^\s+ECU_STAGE_(\w+),$", header, re.M)  # the enum's members
    assert bench.STAGES == python_stages == tuple(name.lower() for name in c_stages)
    path, g = vectors["mrac-aero"]
    stages = bench.qemu_stage_instructions(path, g.ticks)
    assert list(stages) == [f"cm4_stage_instructions_per_tick_{n}" for n in bench.STAGES]
    assert all(isinstance(v, float) and v >= 0 for v in stages.values()), stages
    assert stages["cm4_stage_instructions_per_tick_control_law"] > 0  # the vector runs MRAC
    tick = bench.qemu_instructions(path, g.ticks)
    assert sum(stages.values()) == pytest.approx(tick, rel=0.03)
