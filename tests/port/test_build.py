"""The C sources: warning-free under gcc and clang with the build's flags, no floating point and no
library calls in the core, the generated files are what the current DBC and Python definitions
give."""

import re
import shutil
import subprocess

import pytest

from ecu.port import build, codegen

SOURCES = (*build.CORE_SOURCES, "replay.c")


@pytest.mark.parametrize("cc", ["gcc", "clang"])
@pytest.mark.parametrize("opt", ["-O0", "-O2", "-Os"])
def test_warning_free(toolchains, cc, opt, tmp_path):
    for source in SOURCES:
        done = subprocess.run(
            [
                cc,
                *build.WARNINGS,
                opt,
                "-DECU_WITH_NAMES",
                f"-I{build.PORT_DIR}",
                "-c",
                str(build.PORT_DIR / source),
                "-o",
                str(tmp_path / "x.o"),
            ],  # fmt: skip
            capture_output=True,
            text=True,
        )
        assert done.returncode == 0 and done.stderr == "", f"{cc} {opt} {source}: {done.stderr}"


def test_core_has_no_floating_point_and_no_library_calls(toolchains):
    """On the Cortex-M4 (no FPU in -mcpu=cortex-m4 soft-float) every float operation would be a
    call to __aeabi_f*/__aeabi_d*, and a 64-bit division a call to libgcc's __aeabi_ldivmod. The
    core calls only memset (ecu_init zeroes the state) and memcpy (ecu_params_load copies the
    words in): its 64-bit divisions are its own."""
    obj = build.arm_objects()["ecu_core.c"]
    undefined = subprocess.run(
        ["arm-none-eabi-nm", "-u", str(obj)], capture_output=True, text=True, check=True
    ).stdout.split()
    allowed = {"memset", "memcpy"}
    assert set(undefined[1::2]) <= allowed, undefined
    host = subprocess.run(
        ["nm", "-u", str(build.host_library())], capture_output=True, text=True, check=True
    ).stdout
    assert "sqrt" not in host and "libm" not in host


def test_generated_files_are_current():
    """turbojet.[ch] (cantools) and ecu_constants.h (ecu.port.constants)."""
    for name, text in codegen.generate_sources().items():
        assert (codegen.GENERATED_DIR / name).read_text() == text, (
            f"{name} is stale: run python -m ecu.port.codegen"
        )


def test_no_heap_and_no_float_types_in_the_core_source():
    text = (build.PORT_DIR / "ecu_core.c").read_text() + (build.PORT_DIR / "ecu_core.h").read_text()
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)  # code only, not the comments
    for word in ("float", "double", "malloc", "free(", "<math.h>", "<stdlib.h>"):
        assert word not in text, word


def test_compilers_present(toolchains):
    for tool in ("gcc", "clang", build.ARM_CC, "qemu-system-arm"):
        assert shutil.which(tool), tool


def test_the_first_c_build_says_what_it_is_doing(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(build, "BUILD_DIR", tmp_path)
    library = build.host_library()
    err = capsys.readouterr().err
    assert "ecu.port: compiling libecu_port.so with" in err and str(tmp_path) in err
    assert build.host_library() == library  # built once: the second call says nothing
    assert capsys.readouterr().err == ""
