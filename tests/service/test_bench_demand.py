"""The service port as the demand source of a bench with no Demand frames: arm, throttle, stop;
the CAN Demand winning while present; the switches logged; refusals with their reasons."""

from __future__ import annotations

import pytest

from ecu import modes as M
from ecu import start_sequencer as Q
from ecu.firmware import E2E_NONEWDATA, E2E_OK
from ecu.service import bench_demand as BD
from ecu.service import fault_log as FL
from ecu.service import live
from sil.console.client import ServiceRequestError


def _at_rest(rig) -> None:
    """Sensor and analog frames of a still, cold engine; no Demand frames."""
    i = rig.i
    i.sensor_status = i.analog_status = E2E_OK
    i.demand_status = E2E_NONEWDATA
    i.speed_rpm, i.egt_dk, i.supply_mv, i.pump_ma = 0, 2_900, 22_200, 0


def _codes(rig) -> list[str]:
    return [e["name"] for e in rig.client.faults()]


def test_arm_before_any_reading_is_refused_with_the_reason(rig):
    rig.ticks(5)  # no frame of any kind yet
    with pytest.raises(ServiceRequestError, match="REFUSED: arm: no valid speed and EGT"):
        rig.client.arm()
    assert rig.ecu.out.mode == M.OFF and rig.port.bench.source == BD.NONE


def test_arm_throttle_and_stop_from_the_port(rig):
    _at_rest(rig)
    rig.ticks(3)
    assert rig.client.arm() == "OFF"
    rig.ticks(2)
    assert rig.ecu.out.mode == M.ARMED and rig.ecu.out.seq_state == Q.SPIN_UP
    assert rig.port.bench.source == BD.BENCH
    assert "DEMAND_SOURCE_BENCH" in _codes(rig)
    idle_q24 = rig.ecu.p.idle_q24
    assert rig.ecu.s.demand_q24 == idle_q24  # idle by default
    assert rig.client.throttle(70) == {"demand_pct": 70.0, "source": "BENCH"}
    rig.ticks(2)
    assert rig.ecu.s.demand_q24 == pytest.approx(70 << 24, abs=1 << 10)
    with pytest.raises(ServiceRequestError, match="OUT_OF_RANGE: pct=130"):
        rig.client.throttle(130)
    assert rig.client.throttle(0)["demand_pct"] == idle_q24 / (1 << 24)  # 0: idle
    rig.client.stop()
    rig.ticks(3)
    assert rig.ecu.out.mode == M.OFF  # stopped in the spin-up: no fuel went in
    assert rig.ecu.out.seq_reason == Q.STOPPED
    rig.ticks(300)
    assert rig.ecu.out.mode == M.OFF  # the stop holds; no retry
    assert rig.client.arm() == "OFF"
    rig.ticks(3)
    assert rig.ecu.out.mode == M.ARMED  # a new arm starts again


def test_an_abort_is_logged_once_and_not_retried(rig):
    _at_rest(rig)
    rig.ticks(3)
    rig.client.arm()
    # the starter turns nothing: STARTER_FAILURE after the spin-up timeout
    rig.ticks(rig.ecu.p.seq_spinup_ticks + 50)
    assert rig.ecu.out.seq_reason == Q.STARTER_FAILURE
    rig.ticks(2000)  # 20 s with the bench and no operator
    assert rig.ecu.out.mode == M.OFF
    aborts = [e for e in rig.client.faults() if e["name"].startswith("START_ABORT")]
    assert [(e["name"], e["count"]) for e in aborts] == [("START_ABORT_STARTER_FAILURE", 1)]


def test_the_can_demand_wins_while_present_and_the_switch_is_logged(rig):
    _at_rest(rig)
    rig.ticks(3)
    rig.client.arm()
    rig.ticks(5)
    i = rig.i
    i.demand_cpct, i.arm, i.stop, i.demand_status = 8_000, 1, 0, E2E_OK  # an autopilot appears
    rig.ticks(1)
    assert rig.port.bench.source == BD.CAN and rig.ecu.s.demand_q24 == 80 << 24
    assert _codes(rig)[-1] == "DEMAND_SOURCE_CAN"
    with pytest.raises(ServiceRequestError, match="REFUSED: throttle: CAN Demand frames"):
        rig.client.throttle(60)
    assert rig.ecu.out.mode == M.ARMED  # bumpless: the start goes on under the CAN arm


def test_taking_over_from_a_lost_can_demand_is_bumpless(rig):
    rig.engine_running()  # RUN on CAN Demand frames at 89.68 %N
    rig.ticks(5)
    assert rig.ecu.out.mode == M.RUN
    rig.i.demand_status = E2E_NONEWDATA  # the autopilot goes away
    rig.ticks(3)  # within the hold time the CAN Demand is still the source
    with pytest.raises(ServiceRequestError, match="REFUSED: throttle: CAN Demand frames"):
        rig.client.throttle(50)
    rig.ticks(20)  # past it: the firmware holds idle (DEMAND_LOST); the operator takes over
    assert rig.client.arm() == "RUN"
    assert rig.port.bench.throttle_cpct == 8_968  # at the demand in force, arm held
    rig.ticks(300)  # past the firmware's demand-loss shutdown time
    assert rig.ecu.out.mode == M.RUN and rig.ecu.s.demand_q24 == pytest.approx(
        round(89.68 * 2**24), abs=1 << 12
    )
    assert "DEMAND_SOURCE_BENCH" in _codes(rig)


def test_the_live_record_shows_the_start(rig):
    _at_rest(rig)
    rig.ticks(3)
    rig.client.arm()
    rig.client.stream(100)
    rig.ticks(60)
    rig.client.receive()
    v = rig.client.latest()
    assert v["inputs_valid"] == 1 and v["seq_state"] == Q.SPIN_UP
    assert v["starter"] > 0 and v["igniter"] == 1
    assert 0.5 <= v["seq_time"] <= 0.7  # 60 ticks, and those the requests waited
    assert v["egt_start_limit"] == rig.ecu.p.seq_hot_dk / 10
    assert v["demand_source"] == BD.BENCH and v["demand"] == pytest.approx(
        rig.ecu.p.idle_q24 / (1 << 24), abs=0.01
    )
    assert len(live.FIELDS) == len(rig.client.samples[-1])
    assert FL.code_name(FL.DEMAND_SOURCE_BENCH) == "DEMAND_SOURCE_BENCH"
