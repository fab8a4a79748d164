"""The constants the C port shares with the Python firmware and the DBC: generated/ecu_constants.h
is what ecu.port.constants writes now, the C sources see the Python values under the public names
of ecu_core.h and ecu_frames.h, no hand copy is left, and the compile-time checks fire."""

import re
import subprocess

import pytest

from ecu import faults as F
from ecu import firmware as FW
from ecu import fixedpoint, inlet, limiters, modes, params, pi_design, state
from ecu import start_sequencer as Q
from ecu.node import TELEMETRY_COUNT, EcuNode
from ecu.port import build, codegen, constants
from protocol.codec import Codec
from protocol.dbc import DBC_PATH
from protocol.e2e import COUNTER_MODULO


def test_committed_header_is_a_fresh_generation():
    path = constants.GENERATED_DIR / constants.HEADER_NAME
    assert path.read_text() == constants.header_text(), (
        f"{path} is stale: run python -m ecu.port.codegen"
    )
    assert codegen.generate_sources()[constants.HEADER_NAME] == constants.header_text()


def _python_values() -> dict[str, int]:
    """What the C names must be, from the Python definitions and the DBC."""
    codec = Codec()
    want = {
        "ECU_N_THETA": state.N_THETA,
        "ECU_PI_POINTS": pi_design.PI_POINTS,
        "ECU_SCHED_POINTS": params.SCHED_POINTS,
        "ECU_RATE_BUF_LEN": params.RATE_BUF_LEN,
        "ECU_AP21": state.AP21,
        "ECU_LAM": state.LAM,
        "ECU_PID_I": state.PID_I,
        "ECU_KB": state.KB,
        "ECU_CTRL_MRAC": params.CTRL_MRAC,
        "ECU_CTRL_PID": params.CTRL_PID,
        "ECU_CTRL_OPEN_LOOP": params.CTRL_OPEN_LOOP,
        "ECU_CTRL_PI": params.CTRL_PI,
        "ECU_ABORT_NONE": Q.NO_ABORT,
        "ECU_FAULT_TRANSIENT": F.TRANSIENT,
        "ECU_FAULT_TRIP": FW.TRIP_FAULT,
        "ECU_SEEN_ALL": FW.SEEN_ALL,
        "ECU_RPM_PER_PCT": FW.RPM_PER_PCT,
        "ECU_ACC_EXT_BITS": fixedpoint.ACC_EXT_BITS,
        "ECU_AGE_MAX": FW.AGE_MAX,
        "ECU_EGT_ERROR_MAX_DK": params.EGT_ERROR_MAX_DK,
        "ECU_RATE_MAX_HZ": params.RATE_MAX_HZ,
        "ECU_DUTY_FULL_CPCT": Q.DUTY_FULL_CPCT,
        "ECU_T_STD_CK": inlet.T_STD_CK,
        "ECU_INLET_MIN_DK": inlet.INLET_MIN_DK,
        "ECU_INLET_MAX_DK": inlet.INLET_MAX_DK,
        "ECU_E2E_COUNTER_MODULO": COUNTER_MODULO,
        "ECU_E2E_MAX_DELTA": EcuNode().sensors_check.max_delta,
        "ECU_TELEMETRY_COUNT": TELEMETRY_COUNT,
        "ECU_FAULT_WORD_MASK": 0xFFFF,
        "ECU_RAW_ECU_STARTER_SEQUENCER_STATE_MAX": len(Q.NAMES) - 1,
        "ECU_RAW_ECU_STARTER_ABORT_REASON_MAX": len(Q.REASONS) - 1,
        "ECU_RAW_ECU_STATUS_ECU_MODE_MAX": len(modes.NAMES) - 1,
        "ECU_RAW_ECU_TELEMETRY_EST_AP21_MIN": -(1 << 31),
        "ECU_RAW_ECU_TELEMETRY_EST_AP21_MAX": (1 << 31) - 2,
    }
    want |= {f"ECU_{n}": getattr(modes, n) for n in modes.NAMES}
    want |= {f"ECU_SEQ_{n}": getattr(Q, n) for n in Q.NAMES}
    want |= {f"ECU_ABORT_{n}": getattr(Q, n) for n in Q.REASONS if n != "NONE"}
    want |= {f"ECU_E2E_{n}": getattr(FW, f"E2E_{n}") for n in ("OK", "REPEATED", "NONEWDATA")}
    want |= {f"ECU_E2E_{n}": getattr(FW, f"E2E_{n}") for n in ("WRONGSEQUENCE", "WRONGCRC")}
    want |= {f"ECU_{n}": getattr(limiters, n) for n in dir(limiters) if n.startswith("OWNER_")}
    want |= {f"ECU_FAULT_{name}": bit for bit, name in F.NAMES.items()}
    for name, msg in constants.FRAMES.items():
        want[f"ECU_FRAME_{name}"] = codec[msg].frame_id
        want[f"ECU_E2E_DATA_ID_{name}"] = codec[msg].data_id
    return want


def test_c_sees_the_python_values_under_the_public_names(toolchains, tmp_path):
    """A program that includes ecu_frames.h (and so ecu_core.h) prints every name: the public
    API names are kept and carry the Python and DBC values."""
    want = _python_values()
    body = "\n".join(f'    printf("{n} %lld\\n", (long long)({n}));' for n in want)
    source = tmp_path / "names.c"
    source.write_text(
        '#include <stdio.h>\n#include "ecu_frames.h"\n'
        f"int main(void)\n{{\n{body}\n    return 0;\n}}\n"
    )
    exe = tmp_path / "names"
    subprocess.run(
        ["gcc", *build.WARNINGS, f"-I{build.PORT_DIR}", str(source), "-o", str(exe)],
        check=True,
        capture_output=True,
        text=True,
    )
    out = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout
    got = {name: int(value) for name, value in (line.split() for line in out.splitlines())}
    assert got == want


def test_no_hand_copied_constant_is_left_in_the_c_sources():
    core = (build.PORT_DIR / "ecu_core.c").read_text()
    frames = (build.PORT_DIR / "ecu_frames.c").read_text()
    header = (build.PORT_DIR / "ecu_core.h").read_text()
    assert not re.search(r"#define (F_\w+|SEEN_\w+|RPM_PER_PCT|AGE_MAX|DUTY_FULL_CPCT)\b", core)
    assert not re.search(r"#define ECU_(T_STD_CK|INLET_\w+|N_THETA|RATE_BUF_LEN)\b", core + header)
    assert "enum { ECU_OFF" not in header and "OWNER_SPEED," not in core
    assert not re.search(r"sat_raw\([^;]*, -?\d+, -?\d+\)", frames), "DBC range as a literal"
    assert not re.search(r"data_id\[\d\] = \{\s*\d", frames)
    assert "#define COUNTER_MODULO" not in frames and "#define MAX_DELTA" not in frames


def test_the_header_follows_the_dbc(tmp_path):
    """A changed DBC range changes the header (it is read from the DBC, not restated)."""
    text = DBC_PATH.read_text()
    signal = " SG_ SequencerState : 48|4@1+ (1,0) "
    changed = text.replace(signal + "[0|8]", signal + "[0|9]")
    assert changed != text
    dbc = tmp_path / "changed.dbc"
    dbc.write_text(changed)
    header = constants.header_text(dbc)
    assert "#define ECU_RAW_ECU_STARTER_SEQUENCER_STATE_MAX 9\n" in header
    assert "#define ECU_RAW_ECU_STARTER_SEQUENCER_STATE_MAX 8\n" in constants.header_text()


def test_inconsistent_definitions_are_refused():
    with pytest.raises(constants.ConstantsError, match="not 0, 1, 2"):
        constants._enum("gap", [("A", 0), ("B", 2)])
    with pytest.raises(constants.ConstantsError, match="int32"):
        constants._c_int(1 << 31)
    with pytest.raises(constants.ConstantsError, match="T_STD_CK"):
        constants._check_inlet(1 << 15, 2230, 3330)


@pytest.mark.parametrize("cc", ["gcc", "clang"])
def test_static_assertions_hold_and_fire(toolchains, cc, tmp_path):
    """ecu_core.c compiles with its assertions under C99 (the builds' standard) and C11; a false
    one stops the build."""
    flags = [*build.WARNINGS, f"-I{build.PORT_DIR}", "-c", "-o", str(tmp_path / "x.o")]
    for std in ("-std=c99", "-std=c11"):
        done = subprocess.run(
            [cc, *flags, std, str(build.PORT_DIR / "ecu_core.c")], capture_output=True, text=True
        )
        assert done.returncode == 0 and done.stderr == "", f"{std}: {done.stderr}"
        bad = tmp_path / "bad.c"
        bad.write_text(
            '#include "ecu_core.c"\n'
            "typedef struct { char c; int32_t w; } padded_t;\n"
            "ECU_STATIC_ASSERT(sizeof(padded_t) == 1 + sizeof(int32_t), padded_record);\n"
        )
        done = subprocess.run([cc, *flags, std, str(bad)], capture_output=True, text=True)
        assert done.returncode != 0 and "padded_record" in done.stderr, done.stderr
