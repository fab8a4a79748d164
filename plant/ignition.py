"""Igniter, light-off, blow-out and the fuel that pools in a burner without a flame.

- The igniter (a glow plug) heats towards its working temperature with time constant
  GLOW_TAU_S while powered (and healthy); it lights fuel once at GLOW_READY of it.
- Without a flame the fuel the pump delivers collects in the burner (a pool of liquid and
  vapour) and evaporates into the air through it at a rate proportional to that air flow:
  m g3 / POOL_AIR_KG. The vapour leaves unburnt (purging clears it).
- Light-off: the igniter ready, air through the burner, and the vapour's fuel-air ratio inside
  [FAR_LIGHT, FAR_RICH], all held for LIGHT_DELAY_S.
- With a flame the pump's fuel burns as it arrives and the pool burns off with time constant
  POOL_BURN_S, as fast as the air leaves oxygen for it (up to stoichiometric): a start that
  lights late, on a large pool, burns hot (a hot start).
- Blow-out: lean below the engine's far_lean (EngineParams), rich above FAR_RICH, or no air.
  Nothing lights again without the igniter.
"""

from __future__ import annotations

import math

from numba import njit

from plant.burner import FAR_STOICHIOMETRIC
from plant.jit import JIT

FAR_LIGHT = 0.010  # leanest vapour the igniter lights (above the running lean limit)
FAR_RICH = 0.14  # about twice stoichiometric: richer will not light and blows out
LIGHT_DELAY_S = 0.3
GLOW_TAU_S = 1.0
GLOW_READY = 0.9
POOL_AIR_KG = 0.02
POOL_BURN_S = 0.3
G3_MIN_KG_S = 1e-3  # no flame holds in less air than this

# the ignition state: a slice of the plant's state array
LIT, POOL_KG, LIGHT_TIMER_S, GLOW, UNBURNT_KG, BURNT_POOL_KG = range(6)
SLOTS = 6


@njit(**JIT, inline="always")
def pool_to_gas(pool_kg: float, g3: float, g_pump: float, lit: float) -> float:
    """Fuel leaving the pool into the gas, kg/s: evaporating unburnt without a flame, burning
    with one (as far as the air allows beside the pump's fuel)."""
    if pool_kg <= 0.0 or g3 <= 0.0:
        return 0.0
    if lit == 0.0:
        return pool_kg * g3 / POOL_AIR_KG
    room = FAR_STOICHIOMETRIC * g3 - g_pump
    return min(pool_kg / POOL_BURN_S, room) if room > 0.0 else 0.0


@njit(**JIT, inline="always")
def fuel_to_gas(g_pump: float, g_pool: float, lit: float) -> float:
    """Fuel entering the gas: the pump's (burning) with a flame, else only the pool's vapour."""
    return g_pump + g_pool if lit != 0.0 else g_pool


@njit(**JIT)
def ignition_step(
    z,
    dt: float,
    g3: float,
    g_pump: float,
    g_pool: float,
    igniter_on: float,
    igniter_health: float,
    lean: bool,
) -> None:
    """One step of dt of the ignition state z (LIT, POOL_KG, ...) with the mean flows of the
    step: air into the burner g3, pump fuel g_pump, pool to gas g_pool (kg/s); lean: the
    burner was below its lean limit in the step (plant.flags.LEAN_LIMIT)."""
    glow = z[GLOW]
    target = igniter_on * igniter_health
    z[GLOW] = glow + (target - glow) * -math.expm1(-dt / GLOW_TAU_S)
    lit = z[LIT]
    into_pool = 0.0 if lit != 0.0 else g_pump
    pool = z[POOL_KG] + (into_pool - g_pool) * dt
    z[POOL_KG] = pool if pool > 0.0 else 0.0
    if lit != 0.0:
        z[BURNT_POOL_KG] += g_pool * dt
        if lean or g3 < G3_MIN_KG_S or g_pump + g_pool > FAR_RICH * g3:
            z[LIT] = 0.0  # blow-out
        return
    z[UNBURNT_KG] += g_pump * dt
    ready = z[GLOW] >= GLOW_READY and g3 >= G3_MIN_KG_S
    if ready and FAR_LIGHT * g3 <= g_pool <= FAR_RICH * g3:
        z[LIGHT_TIMER_S] += dt
        if z[LIGHT_TIMER_S] >= LIGHT_DELAY_S:
            z[LIT] = 1.0
            z[LIGHT_TIMER_S] = 0.0
    else:
        z[LIGHT_TIMER_S] = 0.0
