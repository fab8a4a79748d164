"""The start/stop sequencer (ecu.start_sequencer) in the firmware, closed loop on the aero-thermal
plant from standstill: raw integer inputs from the plant's sensors, starter, igniter and pump
back to it, as the CAN nodes carry them."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import pytest

from ecu import modes as M
from ecu import start_sequencer as Q
from ecu.firmware import E2E_OK, Ecu, EcuInputs, EcuOutputs
from ecu.params import EcuParams, ParamError, validate
from plant.aerothermal import AeroThermalPlant
from plant.faults import Fault, FaultKind
from plant.interface import PlantConfig
from plant.pump import pump_flow


@dataclass
class StartRig:
    params: EcuParams = field(default_factory=EcuParams)
    faults: tuple[Fault, ...] = ()
    demand_cpct: int = 5000

    def __post_init__(self) -> None:
        self.ecu = Ecu(self.params)
        self.plant = AeroThermalPlant(PlantConfig(standstill=True, faults=self.faults))
        self.i = EcuInputs()
        self.k = 0
        self.arm = 1
        self.states: list[int] = []  # the sequencer's state, each time it changes

    @property
    def t(self) -> float:
        return self.k / self.params.rate_hz

    def step(self, n: int = 1) -> EcuOutputs:
        i, o = self.i, self.plant.outputs
        for _ in range(n):
            i.tick = self.k & 0xFFFF
            i.speed_rpm = round(o.speed_rpm)
            i.egt_dk = round(o.egt_k * 10.0)
            i.supply_mv = round(o.supply_v * 1000.0)
            i.pump_ma = round(o.pump_current_a * 1000.0)
            i.demand_cpct = self.demand_cpct
            i.arm, i.stop = self.arm, 1 - self.arm
            i.sensor_status = i.analog_status = i.demand_status = E2E_OK
            e = self.ecu.tick(i)
            duty, enabled = e.duty_cpct * 1e-4, bool(e.pump_enable)
            o = self.plant.step(duty, enabled, e.starter_cpct * 1e-4, bool(e.igniter))
            if not self.states or self.states[-1] != e.seq_state:
                self.states.append(e.seq_state)
            self.k += 1
        return self.ecu.out

    def run_until(self, cond, seconds: float) -> float:  # noqa: ANN001
        """Tick until cond(outputs) holds; the time it took (fails if it never does)."""
        t0 = self.t
        for _ in range(round(seconds * self.params.rate_hz)):
            if cond(self.step()):
                return self.t - t0
        raise AssertionError(f"not reached within {seconds} s (states {self.states})")


def test_nominal_start_reaches_idle_through_every_state_in_time() -> None:
    rig = StartRig()
    peak = 0.0
    while rig.ecu.out.mode != M.RUN:
        rig.step()
        peak = max(peak, rig.plant.outputs.egt_k)
        assert rig.t < 25.0, rig.states  # the target: command to idle within 25 s
    assert rig.states[:5] == [Q.SPIN_UP, Q.IGNITION, Q.RAMP, Q.STABILISE, Q.RUN]
    o = rig.ecu.out
    assert o.starter_cpct == 0 and o.igniter == 0 and o.seq_reason == Q.NO_ABORT
    assert rig.plant.outputs.burning == 1.0
    assert peak < rig.params.start_egt_limit_k
    assert rig.plant.outputs.n_pct >= rig.params.start_idle_pct
    rig.step(500)  # the speed loop holds the demand
    assert rig.ecu.out.mode == M.RUN
    assert abs(rig.plant.outputs.n_pct - 50.0) < 2.0


def test_stop_cuts_the_fuel_and_cools_the_engine_before_off() -> None:
    rig = StartRig()
    rig.run_until(lambda o: o.mode == M.RUN, 30.0)
    rig.step(500)
    rig.arm = 0
    rig.step()
    assert rig.ecu.out.mode == M.SHUTDOWN and rig.ecu.out.pump_enable == 0
    rig.run_until(lambda o: o.seq_state == Q.COOL_DOWN, 20.0)
    assert rig.ecu.out.starter_cpct == round(rig.params.cool_duty * 10000)
    took = rig.run_until(lambda o: o.mode == M.OFF, 120.0)
    assert rig.plant.outputs.egt_k < rig.params.cool_egt_k + rig.params.cool_rearm_k
    assert rig.plant.outputs.egt_true_k < 373.0
    assert took < 90.0
    assert rig.ecu.out.starter_cpct == 0 and rig.plant.outputs.burning == 0.0


def _pump_at(rig: StartRig, volts: float) -> float:
    """The fuel the plant's pump delivers at this voltage against about 1 bar (spin-up P3)."""
    model = rig.plant.model
    return pump_flow(volts, model.params.injector_dp_pa, model.pump, 1.0)[0]


def test_no_light_aborts_with_ignition_timeout_and_bounded_fuel() -> None:
    rig = StartRig(faults=(Fault(0.0, FaultKind.IGNITER_FAILURE),))
    took = rig.run_until(lambda o: o.mode == M.SHUTDOWN, 30.0)
    p = rig.params
    assert rig.ecu.out.seq_reason == Q.IGNITION_TIMEOUT
    assert took < 30.0
    assert rig.ecu.out.pump_enable == 0 and rig.ecu.out.igniter == 0
    bound = _pump_at(rig, p.start_ign_v_max) * p.start_ignition_timeout_s
    unburnt = rig.plant.outputs.unburnt_fuel_kg
    assert 0.0 < unburnt < bound
    rig.arm = 0  # the operator releases the arm: cooled (it never lit) and off
    rig.run_until(lambda o: o.mode == M.OFF, 60.0)
    assert rig.plant.outputs.egt_true_k < 373.0


def test_starter_failure_aborts_before_any_fuel() -> None:
    rig = StartRig(faults=(Fault(0.0, FaultKind.STARTER_FAILURE, 0.0),))
    took = rig.run_until(lambda o: o.mode != M.ARMED and o.mode != M.OFF, 15.0)
    assert rig.ecu.out.seq_reason == Q.STARTER_FAILURE
    assert took == pytest.approx(rig.params.start_spinup_timeout_s, abs=0.05)
    assert rig.plant.outputs.unburnt_fuel_kg == 0.0


def test_a_start_over_the_egt_limit_aborts_as_a_hot_start() -> None:
    # a limit just over the target: the EGT overshoots the target as the fuel backs off
    rig = StartRig(
        params=replace(
            EcuParams(), start_egt_target_k=600.0, start_egt_limit_k=605.0, start_egt_margin_k=0.0
        )
    )
    rig.run_until(lambda o: o.mode == M.SHUTDOWN, 30.0)
    assert rig.ecu.out.seq_reason == Q.HOT_START
    assert rig.i.egt_dk > 6050  # what the ECU saw
    assert rig.ecu.out.pump_enable == 0 and rig.ecu.out.duty_cpct == 0
    rig.run_until(lambda o: rig.plant.outputs.burning == 0.0, 3.0)  # fuel cut: the flame dies


def test_a_stop_before_fuel_goes_off_and_after_fuel_cools_down() -> None:
    early = StartRig()
    early.run_until(lambda o: o.seq_state == Q.SPIN_UP, 1.0)
    early.arm = 0
    early.step()
    assert early.ecu.out.mode == M.OFF and early.ecu.out.seq_reason == Q.STOPPED
    late = StartRig()
    late.run_until(lambda o: o.seq_state == Q.RAMP, 15.0)
    late.arm = 0
    late.step()
    assert late.ecu.out.mode == M.SHUTDOWN and late.ecu.out.seq_reason == Q.STOPPED


def test_flameout_in_run_relights_once() -> None:
    starve = (
        Fault(25.0, FaultKind.FUEL_STARVATION, 0.0, duration_s=0.5),
    )  # the supply fails for half a second
    rig = StartRig(faults=starve)
    rig.run_until(lambda o: o.mode == M.RUN, 25.0)
    rig.run_until(lambda o: o.mode == M.ARMED, 10.0)  # flameout seen: relight
    assert rig.t < 27.0  # by the EGT, within 2 s of the flame going out
    rig.step()
    assert rig.ecu.out.seq_state == Q.IGNITION and rig.ecu.out.igniter == 1
    rig.run_until(lambda o: o.mode == M.RUN, 30.0)
    assert rig.plant.outputs.burning == 1.0
    assert rig.ecu.s.relights == 1


def test_flameout_without_relights_left_shuts_down() -> None:
    starve = (Fault(25.0, FaultKind.FUEL_STARVATION, 0.0, duration_s=0.5),)
    rig = StartRig(params=replace(EcuParams(), relight_max=0), faults=starve)
    rig.run_until(lambda o: o.mode == M.RUN, 25.0)
    rig.run_until(lambda o: o.mode != M.RUN, 10.0)
    assert rig.ecu.out.mode == M.SHUTDOWN


@pytest.mark.parametrize(
    ("change", "field_name"),
    [
        ({"start_cutoff_pct": 55.0}, "start_cutoff_pct"),  # over the hand-over speed
        ({"start_egt_target_k": 1250.0}, "start_egt_limit_k"),  # over the hot-start limit
        ({"start_ign_v_max": 25.0}, "start_ign_v_max"),  # over v_max
        ({"start_duty": 0.0}, "start_duty"),
        ({"cool_egt_k": 900.0}, "cool_egt_k"),
        ({"relight_max": 9}, "relight_max"),
        ({"start_purge_s": 20.0}, "start_spinup_timeout_s"),
    ],
)
def test_unsafe_sequencer_parameters_are_refused_by_name(change: dict, field_name: str) -> None:
    with pytest.raises(ParamError, match=field_name):
        validate(replace(EcuParams(), **change))
