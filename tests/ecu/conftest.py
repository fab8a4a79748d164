"""A closed-loop rig: the ECU against the eq. 3.24 fast plant with simple EGT and pump-current
sensors, raw integer inputs as the CAN driver delivers them."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from ecu.firmware import Ecu, EcuInputs, EcuOutputs
from ecu.modes import RUN
from ecu.params import EcuParams
from plant.fast_model import FastEngine

RPM_PER_PCT = 1125.0


@dataclass
class Rig:
    # the plant is the fast model itself: the command lag that matches it is none; its EGT
    # follows the speed alone, not the fuel, so the EGT line's model (ecu.limiters.egt_line_v)
    # does not hold for it, and the EGT loop joins the selection from 100 K, as it must where
    # it is the only protection (docs/ecu.md)
    params: EcuParams = field(
        default_factory=lambda: EcuParams(
            mrac_cmd_lag_s=0.0, egt_zero_fuel_k=0.0, egt_engage_k=100.0
        )
    )
    hot_k: float = 0.0  # EGT offset (hot day, degraded turbine)

    def __post_init__(self) -> None:
        self.ecu = Ecu(self.params)
        self.plant = FastEngine()
        self.i = EcuInputs()
        # inputs that hold unless a step pins them (demand persists once pinned)
        self.demand_cpct = round(self.params.trim_n_pct * 100)
        self.egt_k = self.egt_steady()
        self.k = 0
        self.out: EcuOutputs = self.ecu.out

    @property
    def dt(self) -> float:
        return 1.0 / self.params.rate_hz

    def egt_steady(self) -> float:
        """Static EGT line like our plant's running line near trim (1048 K at 89.68 %N, about
        20 K per %N), plus the hot offset."""
        return 1048.0 + 20.0 * (self.plant.n_pct - 89.68) + self.hot_k

    def step(self, n: int = 1, **override: int) -> EcuOutputs:
        """Run n ticks; keyword arguments pin raw input fields (else they come from the plant)."""
        i = self.i
        for _ in range(n):
            self.egt_k += (self.egt_steady() - self.egt_k) * self.dt / 0.5
            i.tick = self.k
            i.speed_rpm = round(self.plant.n_pct * RPM_PER_PCT)
            i.egt_dk = round(self.egt_k * 10.0)
            # our plant's pump current near trim pressure: 0.25 A + 0.06 A/V + 0.8 A
            i.pump_ma = 1050 + 60 * self.out.pump_mv // 1000 if self.out.pump_enable else 0
            i.supply_mv = 22200
            i.arm = 1
            i.stop = 0
            i.sensor_status = i.analog_status = i.demand_status = 0
            if "demand_cpct" in override:
                self.demand_cpct = override["demand_cpct"]
            i.demand_cpct = self.demand_cpct
            for name, value in override.items():
                setattr(i, name, value)
            o = self.ecu.tick(i)
            if o.mode == RUN:
                self.plant.step(o.pump_mv / 1000.0 - self.params.trim_v, self.dt)
            self.k += 1
        return self.out

    def run_until(self, cond, max_ticks: int, **override: int) -> int:  # noqa: ANN001
        """Tick until cond(outputs) holds; return the number of ticks taken (fails if never)."""
        for n in range(1, max_ticks + 1):
            if cond(self.step(1, **override)):
                return n
        raise AssertionError(f"condition not reached in {max_ticks} ticks")


@pytest.fixture
def make_rig() -> type[Rig]:
    """The Rig class (test modules cannot import conftest under --import-mode=importlib)."""
    return Rig


@pytest.fixture
def rig() -> Rig:
    r = Rig()
    r.step(2)  # OFF -> ARMED -> RUN at trim
    assert r.out.mode == RUN
    return r
