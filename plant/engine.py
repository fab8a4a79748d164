"""The aero-thermal engine of ch. 2: parameters, the derivative of x = [P3, P5, T4, N] and the
fixed-step advance, wiring the component functions (T-MATS style: components are pure functions,
the integrator in plant/integrator.py knows nothing about engines).

RK4 at 1 ms (sec. 2.3); at idle and below, where the jet-pipe plenum is stiffer than RK4 at 1 ms
can follow, each step is split (split_for_stiffness).

State: P3 and P5 in Pa, T4 in K, N in % of N_max (as eq. 2.32). Input: fuel flow (kg/s), or pump
voltage with the gear pump in the loop (fuel flow then follows P3, sec. 2.2).

Two advances share one RK4 step (``_rk4_step``): ``advance``, the running engine of the document
(the flame latched out after a lean blow-out, the hot section's metal at the gas temperature),
which the steady states, the staircases and the schedules use; and ``advance_engine``, the whole
engine from standstill as the plant runs it: the starter (plant/starter.py), the igniter, the
fuel pooled without a flame and light-off (plant/ignition.py), and the hot section's metal
(plant/hot_section.py) as states of their own beside x.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from plant import hot_section as hs
from plant import ignition as ig
from plant import starter as st
from plant.burner import burner
from plant.compressor import CompressorMap, compressor
from plant.flags import LEAN_LIMIT, NOZZLE_CHOKED, PUMP_MAP_CLAMPED
from plant.intake import intake
from plant.integrator import STAGES, rk4_combine, rk4_stage_point
from plant.jit import JIT
from plant.nozzle import PR_LINEAR, nozzle
from plant.plenum import plenum_dp_dt
from plant.pump import PumpTable, pump_flow
from plant.shaft import shaft_domega_dt
from plant.thermo import R_AIR, cp_air
from plant.turbine import TurbineMap, turbine

N_MAX_RPM = 112_500.0  # AMT Olympus (appendix A)
MAX_SPLIT = 16  # most substeps one RK4 step is split into (see split_for_stiffness)


class EngineParams(NamedTuple):
    """Scalars of the model. Defaults: the document's sea-level static test bench (sec. 2.3)."""

    nozzle_area_m2: float  # from the calibration (plant.maps.load_maps().nozzle_area_m2)
    p0_pa: float = 101325.0
    t0_k: float = 288.15
    u0_m_s: float = 0.0
    v_pc_m3: float = 0.002  # compressor plenum
    v_jp_m3: float = 0.001  # jet-pipe plenum
    inertia_kg_m2: float = 0.0002
    cp_fuel: float = 2010.0  # JP8, J/(kg K)
    lhv: float = 42.5e6  # J/kg
    eta_loss: float = 0.98  # burner pressure ratio P4/P3
    tau_b: float = 0.01  # burner time constant, s
    eta_b: float = 0.80
    eta_n: float = 0.98
    eta_m: float = 0.90
    n_max_rpm: float = N_MAX_RPM
    far_lean: float = 0.006  # fuel-air ratio below which the flame goes out
    injector_dp_pa: float = 1.0e5  # pump outlet pressure above P3
    comp_flow_scale: float = 1.0  # health parameters (1.0 = new)
    comp_eff_scale: float = 1.0
    turb_flow_scale: float = 1.0
    turb_eff_scale: float = 1.0
    pump_effectiveness: float = 1.0  # fuel delivered / fuel of a new pump
    hot_section_j_k: float = hs.HEAT_CAPACITY_J_K  # the hot section's metal (hot_section.py)
    hot_section_w_k: float = hs.CONDUCTANCE_W_K
    starter_emf_v_s: float = st.EMF_V_S_RAD  # the starter motor, referred to the rotor
    starter_r_ohm: float = st.RESISTANCE_OHM
    starter_health: float = 1.0  # torque / a new starter's (0: failed)
    igniter_health: float = 1.0  # 1 = heats as new, 0 = failed (no light-off)
    fuel_supply_kg_s: float = 1.0  # the most the tank and line supply (less: starvation)


class EngineModel(NamedTuple):
    """Everything the compiled model reads: parameters and tables."""

    params: EngineParams
    compressor: CompressorMap
    turbine: TurbineMap
    pump: PumpTable


class Stations(NamedTuple):
    """Station values at one state (truth for logging and for the balance checks)."""

    g2: float  # compressor flow, kg/s
    g3: float  # burner inlet flow
    g4: float  # turbine flow
    g6: float  # nozzle flow
    g_fuel: float
    t3: float
    t5: float  # = EGT (T6 = T5, eq. 2.24)
    power_compressor: float
    power_turbine: float
    thrust: float
    flags: int


@njit(**JIT, inline="always")
def stations_at(
    x: np.ndarray,
    g_fuel: float,
    p2: float,
    t2: float,
    model: EngineModel,
    t_metal: float = hs.IN_EQUILIBRIUM,
) -> tuple:
    """All station values at state x, fuel flow g_fuel and compressor inlet (P2, T2), with the
    hot section's metal at t_metal (or in equilibrium with the gas); the EGT is the gas leaving
    the hot section, T6 (= T5 in equilibrium)."""
    g2, g3, g4, g6, g_fuel, t3, _, t6, pwr_c, pwr_t, thrust, flags = _gas_path(
        x, g_fuel, p2, t2, model, t_metal
    )
    return g2, g3, g4, g6, g_fuel, t3, t6, pwr_c, pwr_t, thrust, flags


@njit(**JIT, inline="always")
def _gas_path(
    x: np.ndarray, g_fuel: float, p2: float, t2: float, model: EngineModel, t_metal: float
) -> tuple:
    """stations_at with the turbine's exit T5 beside T6: (g2, g3, g4, g6, g_fuel, T3, T5, T6,
    power of compressor and turbine, thrust, flags)."""
    p = model.params
    p3, p5, t4, n_pct = x[0], x[1], x[2], x[3]
    g2, t3, pwr_c, f_c = compressor(
        p2, t2, p3, n_pct, model.compressor, p.comp_flow_scale, p.comp_eff_scale
    )
    p4 = p.eta_loss * p3  # 2.17
    n_rpm = n_pct * 0.01 * p.n_max_rpm
    g4, t5, pwr_t, f_t = turbine(
        p4, t4, p5, n_rpm, model.turbine, p.turb_flow_scale, p.turb_eff_scale
    )
    g3 = g4 - g_fuel  # 2.16
    eps = hs.effectiveness(g4, cp_air(t5), p.hot_section_w_k)
    t6 = hs.gas_out(t5, t_metal, eps)
    g6, thrust, choked = nozzle(p5, t6, p.p0_pa, p.u0_m_s, p.nozzle_area_m2, p.eta_n)
    flags = f_c | f_t
    if choked:
        flags |= NOZZLE_CHOKED
    if g_fuel <= 0.0 or g3 <= 0.0 or g_fuel < p.far_lean * g3:
        flags |= LEAN_LIMIT  # too little fuel for the air, or no air through the burner
    return g2, g3, g4, g6, g_fuel, t3, t5, t6, pwr_c, pwr_t, thrust, flags


@njit(**JIT)
def stations(x: np.ndarray, g_fuel: float, model: EngineModel) -> tuple:
    """All station values at state x and fuel flow g_fuel (see Stations for the order)."""
    p = model.params
    p2, t2 = intake(p.p0_pa, p.t0_k, p.u0_m_s)
    return stations_at(x, g_fuel, p2, t2, model)


@njit(**JIT, inline="always")
def rates_at(
    x: np.ndarray,
    g_fuel: float,
    lit: float,
    p2: float,
    t2: float,
    model: EngineModel,
    dxdt: np.ndarray,
    t_metal: float = hs.IN_EQUILIBRIUM,
    v_starter: float = 0.0,
) -> tuple[int, float, float]:
    """dx/dt for fuel flow g_fuel (into the gas) and compressor inlet (P2, T2); lit = 1 while
    the flame burns, 0 without one; the hot section's metal at t_metal, the starter motor at
    mean voltage v_starter. Returns (status flags, air into the burner g3, dTm/dt)."""
    p = model.params
    g2, g3, g4, g6, _, t3, t5, t6, pwr_c, pwr_t, _, flags = _gas_path(
        x, g_fuel, p2, t2, model, t_metal
    )
    _, dt4 = burner(
        x[0],
        t3,
        g3,
        x[2],
        g4,
        g_fuel,
        p.t0_k,
        lit,
        p.eta_loss,
        p.eta_b,
        p.lhv,
        p.cp_fuel,
        p.tau_b,
    )
    omega_max = p.n_max_rpm * math.pi / 30.0
    omega = x[3] * 0.01 * omega_max
    dxdt[0] = plenum_dp_dt(t3, p.v_pc_m3, g2, g3)  # 2.12
    dxdt[1] = plenum_dp_dt(t6, p.v_jp_m3, g4, g6)  # 2.22, g5 = g4
    dxdt[2] = dt4  # 2.15
    domega = shaft_domega_dt(omega, pwr_t, pwr_c, p.eta_m, p.inertia_kg_m2)  # 2.31
    if v_starter > 0.0:
        torque = st.starter_torque(
            v_starter, omega, p.starter_emf_v_s, p.starter_r_ohm, p.starter_health
        )
        domega = domega + torque / p.inertia_kg_m2
    dxdt[3] = 100.0 * domega / omega_max  # in %N_max/s
    dtm = 0.0
    if t_metal >= 0.0:
        dtm = hs.metal_rate(g4, cp_air(t5), t5, t6, p.hot_section_j_k)
    return flags, g3, dtm


@njit(**JIT)
def engine_rates(
    x: np.ndarray, g_fuel: float, lit: float, model: EngineModel, dxdt: np.ndarray
) -> int:
    """dx/dt for fuel flow g_fuel at the model's ambient; returns the status flags."""
    p = model.params
    p2, t2 = intake(p.p0_pa, p.t0_k, p.u0_m_s)
    flags, _, _ = rates_at(x, g_fuel, lit, p2, t2, model, dxdt)
    return flags


@njit(**JIT, inline="always")
def pump_fuel_flow(x: np.ndarray, v_pump: float, model: EngineModel) -> tuple[float, bool]:
    """Fuel delivered by the gear pump at voltage v_pump against P3 plus the injector drop."""
    p = model.params
    p_out_gauge = x[0] + p.injector_dp_pa - p.p0_pa
    g, clamped = pump_flow(v_pump, p_out_gauge, model.pump, p.pump_effectiveness)
    return min(g, p.fuel_supply_kg_s), clamped  # a starved pump delivers what reaches it


@njit(**JIT)
def split_for_stiffness(x: np.ndarray, dt: float, params: EngineParams) -> int:
    """How many equal RK4 substeps one step of dt needs to stay stable.

    The fastest mode is the jet-pipe plenum (eq. 2.22) emptying through the nozzle, with rate
    R T5 / V_jp * dg6/dP5. Near P5 = P0 that rate exceeds what RK4 at 1 ms can follow (|lambda dt|
    < 2.78): this is the case at idle and below. The rate is estimated from the state with the
    orifice law g6 = A sqrt(2 rho (P5 - P0)) (T4 >= T5 as the temperature, and a 1.6 factor for the
    turbine's share found from the Jacobian on the running line); the step is split until
    |lambda h| <= 2.
    """
    dp = max(x[1] - params.p0_pa, (PR_LINEAR - 1.0) * params.p0_pa)
    t = max(x[2], 200.0)
    rho = x[1] / (R_AIR * t)
    rate = 1.6 * R_AIR * t / params.v_jp_m3 * params.nozzle_area_m2 * math.sqrt(rho / (2.0 * dp))
    return min(max(int(math.ceil(rate * dt / 2.0)), 1), MAX_SPLIT)


@njit(**JIT, inline="always")
def _rk4_step(
    x: np.ndarray,
    h: float,
    u: float,
    pump_in_loop: bool,
    lit: float,
    pooling: bool,
    g_pool: float,
    t_metal: float,
    v_starter: float,
    p2: float,
    t2: float,
    model: EngineModel,
    work: np.ndarray,
) -> tuple[int, float, float, float]:
    """One RK4 step of h of x with the input u held (pump voltage or fuel flow), the metal at
    t_metal and the starter at v_starter. With pooling, the pump's fuel enters the gas only
    with a flame and the pool's g_pool always (plant.ignition.fuel_to_gas); without, the pump's
    fuel enters the gas, burning or not. Returns (OR of the stages' flags, and the step's
    RK4-weighted means of g3, pump fuel and dTm/dt)."""
    flags = 0
    g3_mean = g_pump_mean = dtm_mean = 0.0
    for stage in range(STAGES):
        xt = rk4_stage_point(x, stage, h, work)
        g_pump = u
        if pump_in_loop:
            g_pump, clamped = pump_fuel_flow(xt, u, model)
            if clamped:
                flags |= PUMP_MAP_CLAMPED
        g_gas = ig.fuel_to_gas(g_pump, g_pool, lit) if pooling else g_pump
        f, g3, dtm = rates_at(xt, g_gas, lit, p2, t2, model, work[stage], t_metal, v_starter)
        flags |= f
        weight = 1.0 / 6.0 if stage == 0 or stage == 3 else 1.0 / 3.0
        g3_mean += weight * g3
        g_pump_mean += weight * g_pump
        dtm_mean += weight * dtm
    rk4_combine(x, h, work)
    return flags, g3_mean, g_pump_mean, dtm_mean


@njit(**JIT, _nrt=False)  # no reference counting: allocates nothing
def advance(
    x: np.ndarray,
    u: float,
    pump_in_loop: bool,
    lit: float,
    n_steps: int,
    dt: float,
    model: EngineModel,
    work: np.ndarray,
) -> tuple[int, float]:
    """n_steps RK4 steps of dt of the running engine with the input u held: the pump voltage
    when pump_in_loop (fuel flow then follows P3), else the fuel flow. x advances in place;
    returns (OR of the flags, lit), lit = 0 once the flame is out (latched: no igniter here)."""
    flags = 0
    p = model.params
    p2, t2 = intake(p.p0_pa, p.t0_k, p.u0_m_s)  # ambient is constant over the call
    for _ in range(n_steps):
        step_flags = 0
        k = split_for_stiffness(x, dt, p)
        h = dt / k
        for _ in range(k):
            f, _, _, _ = _rk4_step(
                x, h, u, pump_in_loop, lit, False, 0.0, hs.IN_EQUILIBRIUM, 0.0, p2, t2, model,
                work,
            )  # fmt: skip
            step_flags |= f
        if step_flags & LEAN_LIMIT:
            lit = 0.0
        if x[3] < 0.0:
            x[3] = 0.0
        flags |= step_flags
    _check_finite(x)
    return flags, lit


@njit(**JIT, inline="always")
def _check_finite(x: np.ndarray) -> None:
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            raise FloatingPointError("engine state is not finite")


# the whole engine's own states beside x (advance_engine), a slice of the plant's state array
IGNITION = 0  # plant.ignition's slots
METAL_K = ig.SLOTS  # the hot section's metal temperature
G3_KG_S = METAL_K + 1  # air into the burner over the last step
STARTER_V = G3_KG_S + 1  # input: the starter motor's mean voltage (duty x supply)
IGNITER_ON = STARTER_V + 1  # input: 1 while the igniter is powered
ENGINE_SLOTS = IGNITER_ON + 1


@njit(**JIT, _nrt=False)  # no reference counting: allocates nothing
def advance_engine(
    x: np.ndarray,
    u: float,
    pump_in_loop: bool,
    z: np.ndarray,
    n_steps: int,
    dt: float,
    model: EngineModel,
    work: np.ndarray,
) -> int:
    """n_steps RK4 steps of dt of the whole engine, from standstill to full speed: x as in
    advance(), and the states z (ENGINE_SLOTS: ignition, the metal, the starter and igniter
    inputs), which advance once per step with the step's mean flows. Returns the flags."""
    flags = 0
    p = model.params
    p2, t2 = intake(p.p0_pa, p.t0_k, p.u0_m_s)
    ign = z[IGNITION : IGNITION + ig.SLOTS]
    for _ in range(n_steps):
        step_flags = 0
        k = split_for_stiffness(x, dt, p)
        h = dt / k
        for _ in range(k):
            lit = ign[ig.LIT]
            g_pool = 0.0
            if ign[ig.POOL_KG] > 0.0:  # (the pump's flow matters only to a pool)
                g_pump_now = u
                if pump_in_loop:
                    g_pump_now, _ = pump_fuel_flow(x, u, model)
                g_pool = ig.pool_to_gas(ign[ig.POOL_KG], z[G3_KG_S], g_pump_now, lit)
            f, g3, g_pump, dtm = _rk4_step(
                x, h, u, pump_in_loop, lit, True, g_pool, z[METAL_K], z[STARTER_V], p2, t2,
                model, work,
            )  # fmt: skip
            g3 = max(g3, 0.0)
            z[G3_KG_S] = g3
            z[METAL_K] += h * dtm
            ig.ignition_step(
                ign, h, g3, g_pump, g_pool, z[IGNITER_ON], p.igniter_health,
                bool(f & LEAN_LIMIT) and lit != 0.0,
            )  # fmt: skip
            step_flags |= f
        if x[3] < 0.0:
            x[3] = 0.0
        flags |= step_flags
    _check_finite(x)
    return flags


@njit(**JIT, _nrt=False)  # no reference counting: allocates nothing
def advance_observed(
    x: np.ndarray,
    u: float,
    pump_in_loop: bool,
    z: np.ndarray,
    n_steps: int,
    dt: float,
    model: EngineModel,
    work: np.ndarray,
    out: np.ndarray,
) -> int:
    """advance_engine(), then the Stations of the new state into out[:11] (flags as a float;
    g_fuel the pump's, T5 the EGT): one compiled call per ECU period for the plant."""
    flags = advance_engine(x, u, pump_in_loop, z, n_steps, dt, model, work)
    g_pump = u
    if pump_in_loop:
        g_pump, _ = pump_fuel_flow(x, u, model)
    lit = z[IGNITION + ig.LIT]
    g_pool = ig.pool_to_gas(z[IGNITION + ig.POOL_KG], z[G3_KG_S], g_pump, lit)
    p = model.params
    p2, t2 = intake(p.p0_pa, p.t0_k, p.u0_m_s)
    g2, g3, g4, g6, _, t3, egt, pwr_c, pwr_t, thrust, st_flags = stations_at(
        x, ig.fuel_to_gas(g_pump, g_pool, lit), p2, t2, model, z[METAL_K]
    )
    out[0], out[1], out[2], out[3], out[4], out[5] = g2, g3, g4, g6, g_pump, t3
    out[6], out[7], out[8], out[9], out[10] = egt, pwr_c, pwr_t, thrust, float(st_flags)
    return flags


def advance_fuel(
    x: np.ndarray,
    g_fuel: float,
    lit: float,
    n_steps: int,
    dt: float,
    model: EngineModel,
    work: np.ndarray,
) -> tuple[int, float]:
    """advance() with the fuel flow commanded."""
    return advance(x, g_fuel, False, lit, n_steps, dt, model, work)


def advance_pump(
    x: np.ndarray,
    v_pump: float,
    lit: float,
    n_steps: int,
    dt: float,
    model: EngineModel,
    work: np.ndarray,
) -> tuple[int, float]:
    """advance() with the gear pump in the loop at voltage v_pump."""
    return advance(x, v_pump, True, lit, n_steps, dt, model, work)
