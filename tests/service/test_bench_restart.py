"""A start from the bench always goes to idle: the bench's throttle belongs to the run it was
set in. In process (the bench demand alone, then the service port on the firmware) and on a
bench as an engineer meets it: a plant and the Python ECU as real-time processes on a loopback
bus, the console arming, throttling and stopping, then arming again."""

from __future__ import annotations

import time

import pytest

from ecu import modes as M
from ecu.firmware import E2E_NONEWDATA, E2E_OK, EcuInputs
from ecu.firmware_params import compile_params
from ecu.params import EcuParams
from ecu.service import bench_demand as BD


def _bench_inputs(bench: BD.BenchDemand, mode: int) -> EcuInputs:
    """The inputs the firmware takes for one tick with no CAN Demand, the engine in ``mode``."""
    i = EcuInputs()
    i.demand_status = E2E_NONEWDATA
    ticked, _ = bench.step(i, mode, 0)
    return ticked


@pytest.mark.parametrize("ended_in", [M.OFF, M.SHUTDOWN, M.FAULT])
def test_the_bench_throttle_ends_with_its_run(ended_in):
    bench = BD.BenchDemand(compile_params(EcuParams()))
    idle = bench.idle_cpct
    assert bench.engage(M.OFF, 0)
    bench.request_arm(M.OFF)
    bench.set_throttle(8_250)
    for mode in (M.ARMED, M.RUN, M.RUN):
        assert _bench_inputs(bench, mode).demand_cpct == 8_250
    ticked = _bench_inputs(bench, ended_in)  # the run ends: a stop, an abort or a trip
    assert (ticked.demand_cpct, ticked.arm) == (idle, 0)
    bench.request_arm(M.OFF)
    for mode in (M.OFF, M.ARMED, M.RUN):
        assert (_bench_inputs(bench, mode).demand_cpct, bench.arm) == (idle, 1)


def test_a_throttle_set_at_rest_is_not_the_start_s_and_one_in_the_run_is_kept():
    bench = BD.BenchDemand(compile_params(EcuParams()))
    bench.engage(M.OFF, 0)
    bench.set_throttle(6_400)  # at rest, before the arm
    bench.request_arm(M.OFF)
    assert _bench_inputs(bench, M.OFF).demand_cpct == bench.idle_cpct
    bench.set_throttle(5_500)  # in the run: an arm while it runs keeps it
    bench.request_arm(M.RUN)
    assert _bench_inputs(bench, M.RUN).demand_cpct == 5_500


def test_a_restart_from_the_port_goes_to_idle(rig):
    """The service port on the firmware: arm, throttle, stop in the spin-up (the engine is OFF
    at once), arm again: the demand the firmware takes is idle, not the last run's."""
    i = rig.i
    i.sensor_status = i.analog_status = E2E_OK
    i.speed_rpm, i.egt_dk, i.supply_mv, i.pump_ma = 0, 2_900, 22_200, 0
    rig.ticks(3)
    idle_q24 = rig.ecu.p.idle_q24
    rig.client.arm()
    rig.client.throttle(77.5)
    rig.ticks(3)
    assert rig.ecu.out.mode == M.ARMED and rig.ecu.s.demand_q24 > idle_q24
    rig.client.stop()
    rig.ticks(3)
    assert rig.ecu.out.mode == M.OFF
    rig.client.throttle(66)  # at rest: not the next start's demand
    assert rig.client.arm() == "OFF"
    rig.ticks(3)
    assert rig.ecu.out.mode == M.ARMED and rig.ecu.s.demand_q24 == idle_q24


@pytest.mark.slow
def test_a_bench_restart_goes_to_idle_not_to_the_old_throttle(
    tmp_path, sil_process, udp_spec, console, stderr_line
):
    spec = udp_spec()
    plant = sil_process("plant", "--bus", spec, "--realtime", "--standstill", cwd=tmp_path)
    ecu = sil_process("ecu", "--bus", spec, "--mode", "realtime", "--serial", "pty", cwd=tmp_path)
    try:
        port = stderr_line(ecu, "service port: ")
        console.until(port, lambda v: v["inputs_valid"] == 1, 30)
        console(port, "arm")
        console.until(port, lambda v: v["mode"] == M.ARMED, 10)
        assert console(port, "throttle", "81") == {"demand_pct": 81.0, "source": "BENCH"}
        assert console(port, "stop")["mode_before"] == "ARMED"
        assert console.until(port, lambda v: v["mode"] == M.OFF, 30)["mode"] == M.OFF
        assert console(port, "arm") == {"mode_before": "OFF"}
        running = console.until(port, lambda v: v["mode"] == M.RUN, 90)
        assert running["mode"] == M.RUN, running
        time.sleep(4.0)  # the old throttle would take it past 60 %N by now
        held = console.until(port, lambda v: True, 0)
    finally:
        for proc in (ecu, plant):
            proc.terminate()
        for proc in (ecu, plant):
            proc.communicate(timeout=20)
    idle_pct = compile_params(EcuParams()).idle_q24 / (1 << 24)
    for sample in (running, held):
        assert sample["mode"] == M.RUN and sample["demand"] == pytest.approx(idle_pct, abs=0.01)
    assert held["speed"] < idle_pct + 5.0, held
