"""`sil console` in a process against `sil ecu --serial pty` in another: live samples print as
they arrive and stay printed when the ECU goes away (or it says so when the ECU does not tick),
the logbook prints by name in its units, and a value to set that is no finite number is refused
naming the parameter."""

from __future__ import annotations

import json
import select
import signal
import time

import pytest

from ecu import logbook as L
from ecu.params import EcuParams
from ecu.service.param_table import ParamTable
from ecu.service.storage import FlashImage
from tests.service.conftest import start_ecu

pytestmark = pytest.mark.slow


def _stop(ecu) -> None:  # noqa: ANN001 (subprocess.Popen)
    ecu.send_signal(signal.SIGTERM)
    ecu.communicate(timeout=30)


def test_live_prints_samples_as_they_come_and_keeps_them_when_the_ecu_goes_away(
    tmp_path, sil_process
):
    ecu, port = start_ecu(tmp_path / "flash.bin", "live")
    console = None
    try:
        console = sil_process(
            "console", port, "--rate", "20", "--timeout", "0.5", "live", "--samples", "100000",
            "--json",
        )  # fmt: skip
        lines: list[str] = []
        deadline = time.monotonic() + 30
        while len(lines) < 5 and time.monotonic() < deadline:  # far fewer than asked for
            ready, _, _ = select.select([console.stdout], [], [], 1.0)
            if ready:
                lines.append(console.stdout.readline())
        assert len(lines) == 5 and console.poll() is None  # printed while still streaming
        ecu.send_signal(signal.SIGKILL)  # the ECU goes away in the middle
        ecu.wait()
        rest, err = console.communicate(timeout=30)
    finally:
        if ecu.poll() is None:
            _stop(ecu)
        if console is not None and console.poll() is None:
            console.kill()
    samples = json.loads("".join(lines) + rest)  # the array closed: valid JSON
    assert console.returncode == 1
    assert err.strip() == (
        f"sil console: live: the ECU stopped sending after {len(samples)} of 100000 samples"
    )
    ticks = [s["tick"] for s in samples]
    assert len(samples) >= 5 and ticks == sorted(ticks) and len(set(ticks)) == len(ticks)


def test_live_from_an_ecu_that_does_not_tick_ends_saying_so(tmp_path, sil):
    ecu, port = start_ecu(tmp_path / "flash.bin", "still", mode="lockstep")  # no plant: no ticks
    try:
        done = sil("console", port, "--timeout", "0.5", "live", "--samples", "4", "--json")
    finally:
        _stop(ecu)
    assert done.returncode == 1 and json.loads(done.stdout) == []
    assert done.stderr.splitlines() == [
        "sil console: live: the ECU stopped sending after 0 of 4 samples"
    ]


def test_the_logbook_prints_the_stored_counts_by_name_in_their_units(tmp_path, sil):
    counts = dict.fromkeys(L.word_names(), 0)
    counts.update(log_runs=12, log_run_time_s=5432, log_run_frac_ticks=17, log_starts=15)
    counts.update(log_aborts_hot_start=2, log_aborts_stopped=1, log_last_shutdown=L.SD_FAULT)
    counts.update(log_last_max_egt_dk=10_519, log_last_max_speed_cpct=9_876)
    flash = tmp_path / "flash.bin"
    with FlashImage(flash) as image:
        image.save(ParamTable(EcuParams()).stored_image(counts))
    ecu, port = start_ecu(flash, "logbook")
    try:
        shown = sil("console", port, "logbook", timeout=60)
        as_json = sil("console", port, "logbook", "--json", timeout=60)
    finally:
        _stop(ecu)
    assert shown.returncode == 0, shown.stderr
    rows = [line.split() for line in shown.stdout.splitlines()]
    assert len(rows) == 13
    assert ["log_run_time_s", "5432", "s"] in rows and ["log_runs", "12"] in rows
    assert ["log_aborts_hot_start", "2"] in rows and ["log_last_shutdown", "FAULT"] in rows
    assert ["log_last_max_egt", "1051.9", "K"] in rows
    assert ["log_last_max_speed", "98.76", "%N"] in rows
    by_name = {r["name"]: r["value"] for r in json.loads(as_json.stdout)}
    assert by_name["log_run_frac_ticks"] == 17 and by_name["log_starts"] == 15
    assert by_name["log_last_max_egt"] == 1051.9 and by_name["log_aborts_slow_accel"] == 0


@pytest.fixture(scope="module")
def ecu_port(tmp_path_factory):
    """A bench ECU in real time with its service port: the pty's path."""
    ecu, port = start_ecu(tmp_path_factory.mktemp("set") / "flash.bin", "set")
    yield port
    _stop(ecu)


@pytest.mark.parametrize(
    ("value", "why"),
    [
        ("nan", "nan is not a finite number"),
        ("-inf", "-inf is not a finite number"),
        ("1e30", "1e+30 is more than its Q7.24 format holds (-128..128)"),
        ("twelve", "'twelve' is not a number"),
    ],
)
def test_set_refuses_a_value_no_finite_number_naming_the_parameter(ecu_port, sil, value, why):
    def values() -> list[int]:
        shown = sil("console", ecu_port, "get", "trim_v", "pid_kp", "--json", timeout=60)
        return [r["raw"] for r in json.loads(shown.stdout)]

    before = values()
    done = sil("console", ecu_port, "set", "trim_v=12.5", f"pid_kp={value}", timeout=60)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.splitlines() == [f"sil console: set pid_kp: {why}"]
    assert values() == before  # nothing written, the valid assignment neither
