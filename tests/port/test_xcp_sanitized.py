"""The C XCP slave under UBSan: the host library built with -fsanitize=undefined (stopping at the
first finding) runs the differential tests of the slave and the node (tests/xcp/test_c_slave.py,
test_c_node.py: the hypothesis-generated bad input, every command at every length, writes of
every parameter, the IEEE arithmetic) in a process of its own."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from ecu.port import build

pytestmark = pytest.mark.slow
UBSAN = Path("/usr/lib/x86_64-linux-gnu/libubsan.so.1")
TESTS = Path(__file__).resolve().parents[1] / "xcp"


@pytest.mark.skipif(not UBSAN.exists(), reason="no libubsan to preload")
def test_the_differential_tests_find_no_undefined_behaviour(toolchains, tmp_path):
    lib = tmp_path / "libecu_port.so"
    flags = (*build.WARNINGS, "-O1", "-g", "-fPIC", "-shared", "-DECU_WITH_NAMES")
    flags += ("-fsanitize=undefined", "-fno-sanitize-recover=all")
    sources = [str(build.PORT_DIR / s) for s in build.CORE_SOURCES]
    subprocess.run(
        ["gcc", *flags, f"-I{build.PORT_DIR}", *sources, "-o", str(lib)],
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    runner = tmp_path / "run.py"
    runner.write_text(
        textwrap.dedent(f"""
        import sys
        from pathlib import Path
        import ecu.port.build, ecu.port.core
        ecu.port.core.host_library = lambda cc=None: Path({str(lib)!r})
        import pytest
        from ecu.port.core import library
        assert library().lib._name == {str(lib)!r}
        sys.exit(pytest.main(["-q", "-x", "-p", "no:cacheprovider",
                              {str(TESTS / "test_c_slave.py")!r},
                              {str(TESTS / "test_c_node.py")!r}]))
        """)
    )
    done = subprocess.run(
        [sys.executable, str(runner)],
        capture_output=True, text=True, timeout=900, cwd=build.PORT_DIR.parents[1],
        env={**os.environ, "LD_PRELOAD": str(UBSAN),
             "UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1"},
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert " passed" in done.stdout and "runtime error" not in done.stderr
