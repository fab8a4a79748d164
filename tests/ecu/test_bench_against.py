"""`sil bench ecu --against REV`: this firmware's tick timed beside the one of a git revision,
after checking the two give the same outputs and state."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import ecu.firmware
from ecu import bench
from ecu.firmware import Ecu, EcuInputs, EcuOutputs


class _DutyOffByOne(Ecu):
    """A firmware whose pump duty differs from this one's by one count from tick 100 on."""

    __slots__ = ()

    def tick(self, i: EcuInputs) -> EcuOutputs:
        out = super().tick(i)
        if i.tick >= 100:
            out.duty_cpct += 1
        return out


def test_a_revision_is_loaded_beside_this_firmware_as_modules_of_its_own() -> None:
    head = bench.firmware_at("HEAD")
    assert head is not ecu.firmware and head.Ecu is not Ecu
    assert ecu.firmware.Ecu is Ecu  # this process's own modules are back in place
    ours, theirs = Ecu(), head.Ecu()
    i, j = EcuInputs(), head.EcuInputs()
    for e, x in ((ours, i), (theirs, j)):
        x.speed_rpm, x.egt_dk, x.supply_mv, x.demand_cpct, x.arm = 100890, 10480, 22200, 8968, 1
        e.tick(x)
    assert ours.out.mode == theirs.out.mode == 2  # both warm-start into RUN


def test_the_same_firmware_gives_the_same_outputs_and_both_are_timed() -> None:
    inputs = bench.scripted_inputs(4_000)
    figures = bench.compare_with(ecu.firmware, inputs, 400, rounds=4)
    assert figures["same_outputs_and_state"] is True
    assert figures["us_per_tick"] > 0 and figures["us_per_tick_against"] > 0
    assert figures["speedup"] > 0


def test_a_firmware_that_answers_differently_is_found_out() -> None:
    other = SimpleNamespace(Ecu=_DutyOffByOne, EcuInputs=EcuInputs)
    inputs = bench.scripted_inputs(4_000)
    assert bench.compare_with(other, inputs, 400, rounds=4)["same_outputs_and_state"] is False


def test_the_command_refuses_an_unknown_revision_and_other_benches(sil) -> None:
    done = sil("bench", "ecu", "--quick", "--against", "no-such-revision")
    assert done.returncode == 2
    assert "no-such-revision" in done.stderr and "Traceback" not in done.stderr
    done = sil("bench", "ecu", "--quick", "--against=--upload-pack=x")
    assert done.returncode == 2 and "not a git revision" in done.stderr
    done = sil("bench", "codec", "--against", "HEAD")
    assert done.returncode == 2 and "--against goes with 'ecu'" in done.stderr


def test_the_command_reports_both_figures_and_the_speed_up(sil) -> None:
    done = sil("bench", "ecu", "--quick", "--against", "HEAD", "--json", timeout=None)
    assert done.returncode == 0, done.stderr
    figures = json.loads(done.stdout)
    assert figures["against"] == "HEAD" and figures["same_outputs_and_state"] is True
    assert figures["us_per_tick"] > 0 and figures["us_per_tick_against"] > 0
    assert figures["speedup"] > 0 and figures["targets_met"]["no_allocation_per_tick"]


def test_the_compiled_tick_is_timed_beside_the_interpreted_one_of_the_same_source() -> None:
    interpreted = bench.interpreted_firmware()
    assert Path(interpreted.__file__).suffix == ".py" and interpreted.Ecu is not Ecu
    figures = bench.run(quick=True)
    assert figures["tick_build"] == "compiled"  # (the session's build: test_compiled_tick)
    assert figures["compiled_same_outputs_and_state"] is True
    # (which is faster is the bench's figure, not this test's: a loaded machine may reorder them)
    assert figures["us_per_tick_interpreted"] > 0 and figures["compiled_speedup"] > 0
