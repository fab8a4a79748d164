"""The ECU knows what it does not know: before valid speed and EGT readings after power-up it
reports no speed, says its readings are invalid, stays OFF and will not arm; it arms only with a
fresh demand; a start that ended with the arm held is not retried until the arm is released.
Both implementations (the Python firmware and the C port, integer for integer)."""

from __future__ import annotations

import pytest

from ecu import faults as F
from ecu import modes as M
from ecu import start_sequencer as Q
from ecu.firmware import E2E_NONEWDATA, E2E_OK, EcuInputs
from ecu.fixedpoint import sat32
from ecu.params import EcuParams
from ecu.port.core import make_ecu

IMPLS = ("python", "c")
TRIM_RPM = 100_890  # 89.68 %N


class Bench:
    """Raw inputs tick by tick: sensor frames on or off, demand frames every 5 ticks or none."""

    def __init__(self, impl: str, params: EcuParams | None = None) -> None:
        self.ecu = make_ecu(impl, params or EcuParams())
        self.i = EcuInputs()
        self.k = 0

    def run(
        self,
        ticks: int,
        *,
        rpm: int = 0,
        egt_dk: int = 2900,
        sensors: bool = True,
        demand: bool = True,
        arm: int = 1,
        stop: int = 0,
        demand_cpct: int = 8968,
    ):
        i = self.i
        for _ in range(ticks):
            i.tick = self.k % 65536
            noise = (self.k * 7919) % 41 - 20 if rpm else 0  # a turning rotor's reading moves
            i.speed_rpm, i.egt_dk = rpm + noise, egt_dk
            o = self.ecu.out
            i.supply_mv = 22200
            i.pump_ma = 1050 + 60 * o.pump_mv // 1000 if o.pump_enable else 0
            i.demand_cpct, i.open_loop_mv, i.arm, i.stop = demand_cpct, 0, arm, stop
            i.sensor_status = E2E_OK if sensors else E2E_NONEWDATA
            i.analog_status = E2E_OK if self.k % 5 == 0 else E2E_NONEWDATA
            i.demand_status = E2E_OK if demand and self.k % 5 == 0 else E2E_NONEWDATA
            o = self.ecu.tick(i)
            self.k += 1
        return o


@pytest.mark.parametrize("impl", IMPLS)
def test_no_reading_yet_no_speed_no_arm(impl):
    b = Bench(impl)
    o = b.run(50, sensors=False)  # armed with a fresh demand, but no sensor frame yet
    assert o.mode == M.OFF and o.inputs_valid == 0
    assert o.n_cpct == 0  # no default (trim) speed: 89.68 %N before the fix
    assert o.pump_enable == 0 and o.starter_cpct == 0
    o = b.run(1)  # the first frame: a still rotor at ambient
    assert o.inputs_valid == 1 and o.mode == M.ARMED and o.seq_state == Q.SPIN_UP


@pytest.mark.parametrize("impl", IMPLS)
def test_an_open_thermocouple_is_no_valid_reading(impl):
    b = Bench(impl)
    o = b.run(30, egt_dk=0)  # speed fine, EGT railed low
    assert o.inputs_valid == 0 and o.mode == M.OFF
    o = b.run(1)
    assert o.inputs_valid == 1 and o.mode == M.ARMED


@pytest.mark.parametrize("impl", IMPLS)
def test_a_late_first_frame_at_speed_takes_over_without_a_false_flameout(impl):
    """A real-time ECU powered up before its engine's first frame: then the engine at trim."""
    b = Bench(impl, EcuParams(start_on=False))
    b.run(40, sensors=False)
    o = b.run(300, rpm=TRIM_RPM, egt_dk=10480)
    assert o.mode == M.RUN and not o.fault_word & F.FLAMEOUT
    assert abs(o.n_cpct - 8968) <= 3 and not o.fault_word & F.SPEED_SUBSTITUTED


@pytest.mark.parametrize("impl", IMPLS)
def test_at_rest_after_power_up_never_enters_run(impl):
    """The old fault: the observer's trim speed before any frame took the ECU straight to RUN,
    then the real 0 rpm read as a flameout and a 'relight' fuelled a still engine."""
    b = Bench(impl)
    modes = set()
    for _ in range(60):
        modes.add(b.run(1, sensors=b.k >= 30).mode)
    assert M.RUN not in modes
    assert not b.ecu.out.fault_word & F.FLAMEOUT


@pytest.mark.parametrize("impl", IMPLS)
def test_no_arm_without_a_fresh_demand(impl):
    b = Bench(impl)
    o = b.run(300, demand=False)
    assert o.mode == M.OFF and o.fault_word & F.DEMAND_LOST
    o = b.run(5)
    assert o.mode == M.ARMED


@pytest.mark.parametrize("impl", IMPLS)
def test_a_stopped_start_waits_for_the_arm_to_be_released(impl):
    b = Bench(impl)
    assert b.run(10).mode == M.ARMED
    assert b.run(5, stop=1).mode == M.OFF  # in the spin-up: no fuel yet, OFF at once
    assert b.ecu.out.seq_reason == Q.STOPPED
    assert b.run(200).mode == M.OFF  # the arm still held: not retried by itself
    b.run(3, arm=0)
    assert b.run(5).mode == M.ARMED  # a new arm request starts again


@pytest.mark.parametrize("impl", IMPLS)
def test_demand_lost_in_a_start_is_not_retried_when_it_returns(impl):
    """The bench fault: with no Demand frames the ECU cycled OFF, ARMED, OFF every tick."""
    b = Bench(impl)
    assert b.run(10).mode == M.ARMED
    changes, last = 0, M.ARMED
    for _ in range(400):
        mode = b.run(1, demand=False).mode
        changes += mode != last
        last = mode
    assert last == M.OFF and changes == 1
    assert b.run(100).mode == M.OFF  # demand back, the arm still held


@pytest.mark.parametrize("impl", IMPLS)
def test_saturations_are_counted_per_instance(impl):
    """Two ECUs ticking in turn: one fed a demand whose Q7.24 value saturates, one not; a reset
    of one leaves the other's count alone (the C port's ecu_t.sat_pending, in Python too)."""
    a, b = Bench(impl), Bench(impl)
    for _ in range(10):
        a.run(1, demand_cpct=65_535)  # 655.35 %N in Q7.24 does not fit: one event a frame
        b.run(1)
    assert a.ecu.out.sat_events == 2 and b.ecu.out.sat_events == 0  # frames every 5 ticks
    sat32(1 << 40)  # a saturation outside any tick (a tool's, a test's) is no ECU's
    assert b.run(1).sat_events == 0
    a.run(4, demand_cpct=65_535)
    a.run(1, demand_cpct=65_535)  # the saturating store's event is added on the next tick
    b.ecu.reset()
    assert a.run(1).sat_events == 3
    assert b.run(10).sat_events == 0
