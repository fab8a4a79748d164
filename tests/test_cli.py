"""The `sil` command line: help, the protocol self-check, clear errors."""

import functools
import json

import pytest

from sil.cli import build_parser, main


@pytest.fixture
def sil(sil):
    """tests/conftest.py's ``sil`` with 120 s for a command."""
    return functools.partial(sil, timeout=120)


def test_help_lists_every_subcommand(sil):
    result = sil("--help")
    assert result.returncode == 0
    sub = build_parser()._subparsers._group_actions[0]
    for name in sub.choices:
        assert name in result.stdout
    assert {"selfcheck", "bench"} <= set(sub.choices)


@pytest.mark.parametrize("name", sorted(build_parser()._subparsers._group_actions[0].choices))
def test_every_subcommand_has_help(name, capsys):
    with pytest.raises(SystemExit) as exc:
        main([name, "--help"])
    assert exc.value.code == 0
    assert "usage: sil" in capsys.readouterr().out


def test_selfcheck_on_the_default_bus(sil):
    result = sil("selfcheck")
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("bus: ")
    assert "self-check passed" in result.stdout


def test_selfcheck_json(sil):
    result = sil("selfcheck", "--bus", "virtual:cli_json", "--json")
    report = json.loads(result.stdout)
    assert result.returncode == 0 and report["ok"]
    assert report["e2e_cases"]["corrupted"] == "WRONGCRC"
    assert len(report["messages"]) >= 9


def test_bad_bus_is_one_line_and_nonzero(sil):
    result = sil("selfcheck", "--bus", "nonsense:x")
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0
    assert "unknown interface 'nonsense'" in result.stderr


def test_bench_codec_json(sil):
    result = sil("bench", "codec", "--quick", "--json")
    figures = json.loads(result.stdout)
    assert figures["codec_encode_us"] > 0 and figures["cantools_decode_us"] > 0


@pytest.mark.parametrize(
    ("command", "spec", "words"),
    [
        (("run", "thesis-5.2-mrac-fast"), "kvaser:0", "Kvaser canlib is unavailable"),
        (("ecu",), "kvaser:0", "kvaser driver is not installed"),
        (("selfcheck",), "pcan:PCAN_USBBUS1", "pcanbasic library not found"),
        (("replay", "{log}"), "vector:0", "vector driver is not installed"),
        (("plant",), "gs_usb:0", "gs_usb driver is not installed"),
    ],
)
def test_a_missing_bus_driver_is_one_line_and_exit_2(tmp_path, command, spec, words, sil):
    log = tmp_path / "frames.log"
    log.write_text("(1.000000) can0 100#0011223344556677\n")
    args = [part.format(log=log) for part in command]
    extra = ("--out", str(tmp_path / "run")) if command[0] == "run" else ()
    result = sil(*args, "--bus", spec, *extra)
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1, result.stderr  # the driver's own warnings swallowed
    assert f"bus {spec}" in result.stderr and words in result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize("events", ["{tmp}", "{tmp}/no-such-folder/events.json"])
def test_bridge_checks_its_events_file_before_it_starts(tmp_path, events, sil):
    import time

    faults = tmp_path / "faults.toml"
    faults.write_text('[[bus_fault]]\nkind = "drop"\nids = ["PlantSensors"]\nstart_s = 0\n')
    argv = ["bridge", str(faults), "--bus", "virtual:b1", "--ecu-bus", "virtual:b2"]
    t0 = time.monotonic()
    result = sil(*argv, "--duration", "60", "--events", events.format(tmp=tmp_path))
    assert result.returncode == 2 and "argument --events" in result.stderr
    assert time.monotonic() - t0 < 30  # refused at once, not after the 60 s bridge


def test_a_commissioning_the_ecu_refuses_is_named_before_anything_runs(tmp_path, capsys):
    bad = tmp_path / "engine.json"
    bad.write_text(
        '{"format": "turbojet-sil commissioning 1", "trim_N_pct": -5, "trim_V": -12,'
        ' "Ap_row2": [-1.8, -2.3], "Lambda": 4.8, "Theta_row2": [-0.18, 0.0]}'
    )
    out = tmp_path / "run"
    argv = ["run", "thesis-5.4-staircase", "--mode", "inproc", "--commission", str(bad)]
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"sil run: {bad}: the ECU refuses this commissioning: trim_n_pct=-5.0: "
                   "must be in (0, 110)"]  # fmt: skip


def test_demo_help_states_its_own_output_folder(capsys) -> None:
    try:
        main(["demo", "--help"])
    except SystemExit:
        pass
    out = " ".join(capsys.readouterr().out.split())
    assert "--out DIR output folder (default: out/demo, a folder per controller inside" in out
