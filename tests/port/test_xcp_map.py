"""What the C XCP slave shares with the Python one: generated/ecu_xcp_map.h is what
ecu.port.xcp_map writes now, its map and tables are the Python definitions, and the run record
covers every parameter (its word, a recipe, a derived word, or a commissioning parameter)."""

from __future__ import annotations

import random
import subprocess

from ecu.firmware_params import compile_params
from ecu.params import EcuParams
from ecu.port import build, codegen, xcp_map
from ecu.port import xcp_run as R
from ecu.port.core import param_words
from ecu.service.param_table import TABLE, _with
from ecu.xcp import codes as C
from ecu.xcp import memory as MEM
from ecu.xcp import slave as S


def test_committed_map_is_a_fresh_generation():
    path = xcp_map.GENERATED_DIR / xcp_map.HEADER_NAME
    assert path.read_text() == xcp_map.header_text(), f"{path} is stale: python -m ecu.port.codegen"
    assert codegen.generate_sources()[xcp_map.HEADER_NAME] == xcp_map.header_text()


def test_c_sees_the_python_map(toolchains, tmp_path):
    want = {
        "ECU_XCP_CAL_BASE": MEM.CAL_BASE,
        "ECU_XCP_MEAS_BASE": MEM.MEAS_BASE,
        "ECU_XCP_BENCH_BASE": MEM.BENCH_BASE,
        "ECU_XCP_AXIS_BASE": MEM.AXIS_BASE,
        "ECU_XCP_TEXT_BASE": MEM.TEXT_BASE,
        "ECU_XCP_PARAMS": len(TABLE),
        "ECU_XCP_MEAS_SIZE": MEM.MEAS_SIZE,
        "ECU_XCP_MEASUREMENTS": len(MEM.MEASUREMENTS),
        "ECU_XCP_MAX_FRAMES": S.MAX_FRAMES,
        "ECU_XCP_ERR_VERIFY": C.Err.VERIFY,
        "ECU_XCP_CMD_ALLOC_ODT_ENTRY": C.Cmd.ALLOC_ODT_ENTRY,
        "ECU_XCP_P_EGT_LIMIT_K": R.INDEX["egt_limit_k"],
        "ECU_XCP_P_ACCEL_RATE_PCT_S_11": R.INDEX["accel_rate_pct_s[11]"],
        "ECU_XCP_RUN_WORDS": R.RUN_WORDS,
        "ECU_XCP_STORED": len(R.STORED),
    }
    body = "\n".join(f'    printf("{n} %lld\\n", (long long)({n}));' for n in want)
    source = tmp_path / "names.c"
    source.write_text(
        f'#include <stdio.h>\n#include "ecu_xcp.h"\nint main(void)\n{{\n{body}\n    return 0;\n}}\n'
    )
    exe = tmp_path / "names"
    subprocess.run(
        ["gcc", *build.WARNINGS, f"-I{build.PORT_DIR}", str(source), "-o", str(exe)],
        check=True,
        capture_output=True,
        text=True,
    )
    out = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout
    assert {n: int(v) for n, v in (line.split() for line in out.splitlines())} == want


def test_every_parameter_has_its_way_to_the_firmware():
    covered = (
        set(R.IDENTITY)
        | {r.param for r in R.RECIPES}
        | set(R.DERIVED_INPUTS)
        | set(R.COMMISSIONING)
    )
    assert covered >= {spec.name for spec in TABLE}
    assert not set(R.IDENTITY) & {r.param for r in R.RECIPES} - {"idle_pct"}
    assert {r.word for r in R.RECIPES} | set(R.SWAPPED.values()) <= set(R.WORD)


def test_an_identity_parameter_is_its_firmware_word_at_any_raw():
    rng = random.Random(1)
    base = EcuParams()
    for name, word in R.IDENTITY.items():
        spec = TABLE[R.INDEX[name]]
        for raw in (spec.raw_lo, spec.raw_hi, rng.randint(spec.raw_lo, spec.raw_hi)):
            params = _with(base, spec, spec.to_value(raw))
            try:
                words = param_words(compile_params(params))
            except ValueError:
                continue  # the set refused as a whole (the rules say when)
            assert words[R.WORD[word]] == raw, (name, raw)


def test_the_run_record_lays_out_the_set():
    from ecu.service.port import boot

    table = boot(EcuParams(), None).table
    words = R.run_record(table)
    assert len(words) == R.RUN_WORDS and all(-(1 << 31) <= w < 1 << 31 for w in words)
    raws = dict(zip((s.name for s in TABLE), table.raws(), strict=True))
    assert words[R.RUN_STORED : R.RUN_STORED + len(R.STORED)] == [raws[n] for n in R.STORED]
    assert words[R.RUN_RECIPES] == len(R.recipes(EcuParams()))
