"""`python -m ecu.port.export`: a parameter set as a const ecu_params_t, equal word for word to
what the golden vectors and the ctypes wrapper load."""

import subprocess
import sys

import pytest

from ecu.firmware_params import compile_params
from ecu.params import preset
from ecu.port import build, export
from ecu.port.core import param_words

MAIN = """
#include <string.h>
#include "ecu_core.h"
extern const ecu_params_t exported;
static const int32_t words[ECU_PARAM_WORDS] = {%s};
int main(void)
{
    static ecu_params_t loaded;
    static ecu_t ecu;
    ecu_inputs_t in = {0};
    if (ecu_params_load(&loaded, words, ECU_PARAM_WORDS) >= 0) return 3;
    if (memcmp(&loaded, &exported, sizeof loaded) != 0) return 1;
    ecu_init(&ecu, &exported);
    return ecu_tick(&ecu, &in)->mode == ECU_OFF ? 0 : 4;
}
"""


@pytest.mark.parametrize("name", ["default", "sec5_3_mrac_aero", "sec4_2_estimator"])
def test_exported_constant_equals_the_loaded_words(tmp_path, name):
    p = compile_params(preset(name))
    (tmp_path / "params.c").write_text(export.to_c(p, "exported", name))
    (tmp_path / "main.c").write_text(MAIN % ", ".join(str(w) for w in param_words(p)))
    exe = tmp_path / "check"
    subprocess.run(
        [
            build.host_compiler(),
            *build.WARNINGS,
            f"-I{build.PORT_DIR}",
            str(tmp_path / "params.c"),
            str(tmp_path / "main.c"),
            str(build.PORT_DIR / "ecu_core.c"),
            "-o",
            str(exe),
        ],  # fmt: skip
        check=True,
    )
    assert subprocess.run([str(exe)]).returncode == 0


def test_bad_parameters_are_refused_by_name():
    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-m", "ecu.port.export", *args], capture_output=True, text=True
        )

    done = run("--param", "bogus=1")
    assert done.returncode == 2 and "'bogus=1'" in done.stderr and done.stdout == ""
    done = run("--param", "v_max=40")
    assert done.returncode == 2 and "v_max" in done.stderr
    done = run("--preset", "sec5_2_mrac_fast", "--name", "fast")
    assert done.returncode == 0 and "const ecu_params_t fast = {" in done.stdout
