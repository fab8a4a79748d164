"""The gain-scheduled PI baseline's gains, designed from the commissioned fast model (eq. 3.5).

At each scheduling speed N_k the fast model is linearised about its steady state there:

    dN'' = a21 dN + a22 dN' + (Lambda + Th1 dN + Th2 dN^2) dV
    steady input  u0 = -a21 dN_k / b,  b = Lambda + Th1 dN_k + Th2 dN_k^2  (the input's gain)
    G(s) = b / (s^2 - a22 s - a21_k),   a21_k = a21 + (Th1 + 2 Th2 dN_k) u0

and the PI C(s) = Kp + Ki / s = Kp (s + z) / s is placed by the loop-shaping rule NASA's
TTECTrA uses for its set-point controller: the open loop C G crosses over at w_c
(pi_bandwidth, 1.75 rad/s) with the phase margin PM (pi_phase_margin, 50 degrees): the PI's
phase at w_c is -180 + PM - arg G, kept within [-80, -5] degrees (a PI only lags; its zero
z = w_c tan(-phase) stays below 5.7 w_c); where the margin that leaves is under 50 degrees,
w_c steps down by 10 % until it is not. Then |C G| = 1 at w_c gives Kp, and Ki = Kp z.
Configuration-time code (floats), outside the tick.
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

PI_POINTS = 9
PI_N0_PCT = 60.0  # first scheduling speed; below it the PI keeps its gains
PI_STEP_PCT = 5.0  # 60, 65, ..., 100 %N
PHASE_LIMITS_DEG = (-80.0, -5.0)
MIN_MARGIN_DEG = 50.0


class PiDesignError(ValueError):
    """The model admits no PI with the margin at any bandwidth (e.g. an input gain <= 0)."""


@dataclass(frozen=True)
class PiPoint:
    n_pct: float
    kp: float  # V/%N
    ki: float  # V/(%N s)
    wc: float  # rad/s, the crossover the gains give
    margin_deg: float
    plant: tuple[float, float, float]  # b, a21_k, a22: G(s) = b / (s^2 - a22 s - a21_k)


def schedule_speeds() -> tuple[float, ...]:
    return tuple(PI_N0_PCT + k * PI_STEP_PCT for k in range(PI_POINTS))


def linearised_fast_model(
    dn: float, a21: float, a22: float, lam: float, th1: float, th2: float
) -> tuple[float, float, float]:
    """(b, a21_k, a22) of the fast model about its steady state at deviation dn (%N)."""
    b = lam + th1 * dn + th2 * dn * dn
    if b <= 0.0:
        raise PiDesignError(f"input gain {b:.3g} <= 0 at dN = {dn:+.1f} %N")
    u0 = -a21 * dn / b
    return b, a21 + (th1 + 2.0 * th2 * dn) * u0, a22


def plant_response(plant: tuple[float, float, float], w: float) -> complex:
    b, a21, a22 = plant
    s = 1j * w
    return b / (s * s - a22 * s - a21)


def pi_for(
    plant: tuple[float, float, float], wc: float, margin_deg: float
) -> tuple[float, float, float, float]:
    """(Kp, Ki, w_c used, margin achieved) for one linearised plant."""
    if margin_deg < MIN_MARGIN_DEG:
        raise PiDesignError(f"phase margin {margin_deg} deg < {MIN_MARGIN_DEG} deg")
    w = wc
    for _ in range(40):
        g = plant_response(plant, w)
        arg_g = math.degrees(cmath.phase(g))
        if arg_g > 0.0:  # principal value: a lagging plant's phase lies in (-360, 0]
            arg_g -= 360.0
        want = -180.0 + margin_deg - arg_g
        phase = min(max(want, PHASE_LIMITS_DEG[0]), PHASE_LIMITS_DEG[1])
        achieved = 180.0 + arg_g + phase
        if achieved >= MIN_MARGIN_DEG:
            z = w * math.tan(math.radians(-phase))
            kp = 1.0 / (abs(g) * math.hypot(1.0, z / w))
            return kp, kp * z, w, achieved
        w *= 0.9
    raise PiDesignError(f"no crossover down to {w:.3g} rad/s gives {MIN_MARGIN_DEG} deg")


def design_schedule(
    trim_n_pct: float,
    ap_row2: tuple[float, float],
    lam: float,
    theta_row2: tuple[float, float],
    wc: float,
    margin_deg: float,
) -> tuple[PiPoint, ...]:
    """The PI gains at each scheduling speed from the commissioned model (printed convention:
    Theta_f pairs with [dN dV, dN^2 dV])."""
    points = []
    for n in schedule_speeds():
        plant = linearised_fast_model(n - trim_n_pct, *ap_row2, lam, *theta_row2)
        kp, ki, w, margin = pi_for(plant, wc, margin_deg)
        points.append(PiPoint(n, kp, ki, w, margin, plant))
    return tuple(points)
