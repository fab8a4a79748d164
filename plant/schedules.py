"""Fuel schedules from the plant, in the standard gas-turbine form: against shaft speed, the
steady running line, the acceleration line (the most fuel the engine may take at that speed)
and the deceleration floor (the least), each as fuel flow and as the gear pump's voltage.

Both limits are found with the shaft held at its speed ("frozen speed": the plenums and the
burner settle in milliseconds, the shaft in about a second, so in a fast transient the gas path
sits on its frozen-speed state while the speed lags):

- acceleration line: the largest fuel flow at which, at frozen speed, the gas leaving the
  turbine (EGT, T5) stays at or under the EGT limit, the compressor keeps its surge margin
  (surge pressure ratio over working pressure ratio, less one) and the burner stays under its
  rich limit;
- deceleration floor: the smallest fuel flow whose fuel-air ratio keeps the lean blow-out margin
  above the burner's lean limit (far_lean).

Voltages are what the plant's pump needs to deliver that fuel against the frozen state's P3. The
shaft's acceleration on each line is reported too: what the schedule lets the engine do.

No two engines are alike, and the ECU's schedules must hold for every engine it may be fitted to:
`fleet_schedule` takes the lowest acceleration line and the highest deceleration floor over the
nominal engine and every corner of a health spread (each of the compressor's and the turbine's
efficiency and flow scalars at 1 +- spread). A corner that cannot run at a speed within the limits
is left out there (its EGT loop holds it below that speed). The fleet line keeps at least
KEEP_ACCEL of the nominal engine's own fuel margin over its steady line, so that the nominal
engine still accelerates at every speed (near full speed a hot corner's line falls under its
steady line).

The acceleration schedule (the ECU's Ndot limit) allows, at each speed, RATE_MARGIN more than the
shaft acceleration the nominal engine has on the acceleration line, and at least NDOT_MIN_PCT_S:
an engine that accelerates faster than that on the line gets more fuel than the line means (a
pump stronger than the ECU has learnt), and the ECU's rate loop takes it back.
"""

from __future__ import annotations

import csv
import itertools
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from plant.compressor import surge_margin as compressor_surge_margin
from plant.engine import EngineModel, Stations, engine_rates, stations
from plant.intake import intake
from plant.linearise import pump_voltage_for
from plant.steady_line import running_line
from plant.trim import SCALE, SteadyState
from protocol import strict_json

SPEEDS_PCT = tuple(float(n) for n in range(45, 101, 5))
EGT_LIMIT_K = 1280.0  # the ECU's EGT limit (ecu.params.EcuParams.egt_limit_k)
SURGE_MARGIN = 0.10  # surge pressure ratio / working pressure ratio - 1, at least
LEAN_MARGIN = 0.30  # fuel-air ratio at least (1 + margin) times the lean limit
RICH_FAR = 0.05  # fuel-air ratio the burner must stay under
MAX_FUEL_FACTOR = 4.0  # the acceleration line is searched up to this times the steady fuel
HEALTH_SPREAD = 0.05  # the fleet: every corner of +-5 % on the four health scalars
KEEP_ACCEL = 0.5  # the fleet line keeps at least this of the nominal's fuel margin over steady
RATE_MARGIN = 0.2  # the acceleration schedule: the nominal's rate on the line, plus this
NDOT_MIN_PCT_S = 5.0  # ... and never less (under it, speed noise would work the rate loop)
IDLE_PCT = 55.0  # line_rise_s from here (the transients' idle: every engine of +-5 % runs there)
THRUST_FRACTION = 0.95  # line_rise_s to this fraction of the thrust change (14 CFR 33.73)


class ScheduleError(ValueError):
    """The plant admits no schedule point (no steady state, or no frozen-speed state)."""


@dataclass(frozen=True)
class SchedulePoint:
    n_pct: float
    steady_fuel_kg_s: float
    steady_v: float
    steady_egt_k: float
    accel_fuel_kg_s: float
    accel_v: float
    accel_limited_by: str  # "egt", "surge", "rich" or "search" (none within MAX_FUEL_FACTOR)
    accel_egt_k: float
    accel_surge_margin: float
    accel_rate_pct_s: float  # the (nominal) engine's shaft acceleration on the line at this speed
    decel_fuel_kg_s: float
    decel_v: float
    decel_far: float
    decel_rate_pct_s: float  # shaft deceleration on the floor (negative)
    ndot_pct_s: float  # the acceleration schedule: the shaft acceleration the ECU allows here


def _rates(model: EngineModel, x: np.ndarray, g_fuel: float) -> np.ndarray:
    dxdt = np.empty(4)
    engine_rates(x, g_fuel, 1.0, model, dxdt)
    return dxdt


def frozen_state(model: EngineModel, x0: np.ndarray, g_fuel: float) -> np.ndarray:
    """The gas path's state [P3, P5, T4] settled at fuel flow g_fuel with N held at x0[3]
    (Newton on their rates in scaled variables)."""
    x = np.asarray(x0, dtype=float).copy()
    for _ in range(30):
        f = _rates(model, x, g_fuel)[:3] / SCALE[:3]
        if np.max(np.abs(f)) < 1e-10:
            return x
        jac = np.empty((3, 3))
        for j in range(3):
            h = 1e-6 * SCALE[j]
            xp = x.copy()
            xp[j] += h
            jac[:, j] = (_rates(model, xp, g_fuel)[:3] / SCALE[:3] - f) / (h / SCALE[j])
        step = np.linalg.solve(jac, f) * SCALE[:3]
        x[:3] -= np.clip(step, -0.2 * x[:3], 0.2 * x[:3])  # damped: pressures stay positive
    raise ScheduleError(f"no frozen-speed state at N = {x0[3]:.1f} %, {g_fuel * 1e3:.2f} g/s")


def surge_margin(model: EngineModel, x: np.ndarray) -> float:
    """Surge pressure ratio over the working one, less one, at the state x."""
    p = model.params
    p2, t2 = intake(p.p0_pa, p.t0_k, p.u0_m_s)
    return float(compressor_surge_margin(model.compressor, p2, t2, x[0], x[3]))


def _stations(model: EngineModel, x: np.ndarray, g_fuel: float) -> Stations:
    return Stations(*stations(x, g_fuel, model))


def _bisect(ok: Callable[[float], bool], lo: float, hi: float) -> tuple[float, float]:
    """(lo, hi) 1e-9 apart in relative terms around the boundary, ok(lo) True, ok(hi) False."""
    while hi - lo > 1e-9 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo, hi


def steady_at_speed(
    model: EngineModel, n_pct: float, line: dict[str, np.ndarray]
) -> tuple[float, SteadyState]:
    """The fuel flow and steady state of speed n_pct: Newton on all four rates with the fuel
    flow as the unknown in place of N, from the running line (plant.steady_line) interpolated."""
    guess = [np.interp(n_pct, line["N_pct"], line[c]) for c in ("P3_Pa", "P5_Pa", "T4_K")]
    z = np.array([*guess, np.interp(n_pct, line["N_pct"], line["fuel_kg_s"])])
    z_scale = np.array([*SCALE[:3], 1e-3])

    def f(z: np.ndarray) -> np.ndarray:
        return _rates(model, np.array([z[0], z[1], z[2], n_pct]), z[3]) / SCALE

    for _ in range(30):
        r = f(z)
        if np.max(np.abs(r)) < 1e-10:
            x = np.array([z[0], z[1], z[2], n_pct])
            st = _stations(model, x, z[3])
            return float(z[3]), SteadyState(x=x, stations=st, residual=float(np.max(np.abs(r))))
        jac = np.empty((4, 4))
        for j in range(4):
            zp = z.copy()
            zp[j] += 1e-6 * z_scale[j]
            jac[:, j] = (f(zp) - r) / (1e-6 * z_scale[j])
        z -= np.clip(np.linalg.solve(jac, r), -0.2 * z, 0.2 * z)  # damped, all stay positive
    raise ScheduleError(f"no steady state at N = {n_pct:.1f} %")


def schedule_point(
    model: EngineModel,
    n_pct: float,
    line: dict[str, np.ndarray],
    egt_limit_k: float = EGT_LIMIT_K,
    surge_margin_min: float = SURGE_MARGIN,
    lean_margin: float = LEAN_MARGIN,
) -> SchedulePoint:
    """The schedule at speed n_pct (line: the running line, plant.steady_line.running_line)."""
    g_ss, steady = steady_at_speed(model, n_pct, line)
    x_ss = steady.x
    far_lean = model.params.far_lean
    cache: dict[float, np.ndarray] = {}

    def frozen(g: float) -> np.ndarray:
        if g not in cache:
            cache[g] = frozen_state(model, x_ss, g)
        return cache[g]

    def limits(g: float) -> str | None:
        """The first limit fuel flow g breaks at frozen speed, or None."""
        x = frozen(g)
        st = _stations(model, x, g)
        if st.t5 > egt_limit_k:
            return "egt"
        if surge_margin(model, x) < surge_margin_min:
            return "surge"
        if g > RICH_FAR * st.g3:
            return "rich"
        return None

    g_hi = MAX_FUEL_FACTOR * g_ss
    broken = limits(g_ss)
    if broken is not None:
        raise ScheduleError(f"N = {n_pct:.1f} %: the steady line itself breaks the {broken} limit")
    if limits(g_hi) is None:
        g_acc, by = g_hi, "search"
    else:
        g_acc, above = _bisect(lambda g: limits(g) is None, g_ss, g_hi)
        by = limits(above) or "egt"

    def lean_ok(g: float) -> bool:
        return g >= (1.0 + lean_margin) * far_lean * _stations(model, frozen(g), g).g3

    if not lean_ok(g_ss):
        raise ScheduleError(f"N = {n_pct:.1f} %: the steady line is inside the lean margin")
    _, g_dec = _bisect(lambda g: not lean_ok(g), 0.05 * g_ss, g_ss)
    x_acc, x_dec = frozen(g_acc), frozen(g_dec)
    st_acc, st_dec = _stations(model, x_acc, g_acc), _stations(model, x_dec, g_dec)
    accel_rate = float(_rates(model, x_acc, g_acc)[3])
    return SchedulePoint(
        n_pct=n_pct,
        steady_fuel_kg_s=g_ss,
        steady_v=pump_voltage_for(model, x_ss, g_ss),
        steady_egt_k=steady.stations.t5,
        accel_fuel_kg_s=g_acc,
        accel_v=pump_voltage_for(model, x_acc, g_acc),
        accel_limited_by=by,
        accel_egt_k=st_acc.t5,
        accel_surge_margin=surge_margin(model, x_acc),
        accel_rate_pct_s=accel_rate,
        decel_fuel_kg_s=g_dec,
        decel_v=pump_voltage_for(model, x_dec, g_dec),
        decel_far=g_dec / st_dec.g3,
        decel_rate_pct_s=float(_rates(model, x_dec, g_dec)[3]),
        ndot_pct_s=allowed_rate(accel_rate),
    )


def schedule(
    model: EngineModel,
    speeds_pct: tuple[float, ...] = SPEEDS_PCT,
    egt_limit_k: float = EGT_LIMIT_K,
    surge_margin_min: float = SURGE_MARGIN,
    lean_margin: float = LEAN_MARGIN,
    progress: Callable[[int, int], None] | None = None,
) -> list[SchedulePoint]:
    """The schedule at each speed, rising."""
    line = running_line(model)
    out: list[SchedulePoint] = []
    for k, n in enumerate(sorted(speeds_pct)):
        out.append(schedule_point(model, n, line, egt_limit_k, surge_margin_min, lean_margin))
        if progress is not None:
            progress(k + 1, len(speeds_pct))
    return out


def allowed_rate(line_rate_pct_s: float) -> float:
    """The acceleration schedule's point for the nominal engine's rate on the line."""
    return max(NDOT_MIN_PCT_S, (1.0 + RATE_MARGIN) * line_rate_pct_s)


def rate_at_voltage(
    model: EngineModel, line: dict[str, np.ndarray], point: SchedulePoint, v: float
) -> float:
    """The shaft acceleration of the point's engine (line: its running line) at frozen speed with
    the pump at v (V), at most the acceleration line's fuel flow."""
    _, steady = steady_at_speed(model, point.n_pct, line)

    def under(g: float) -> bool:
        return pump_voltage_for(model, frozen_state(model, steady.x, g), g) < v

    g, _ = _bisect(under, point.steady_fuel_kg_s, point.accel_fuel_kg_s)
    return float(_rates(model, frozen_state(model, steady.x, g), g)[3])


def health_corners(model: EngineModel, spread: float) -> list[EngineModel]:
    """The engine at each corner of the health spread (efficiency and flow scalars of the
    compressor and the turbine at 1 +- spread)."""
    levels = (1.0 - spread, 1.0 + spread)
    return [
        model._replace(
            params=model.params._replace(
                comp_eff_scale=ce, comp_flow_scale=cf, turb_eff_scale=te, turb_flow_scale=tf
            )
        )
        for ce, cf, te, tf in itertools.product(levels, repeat=4)
    ]


def kept_point(
    model: EngineModel, line: dict[str, np.ndarray], point: SchedulePoint
) -> SchedulePoint:
    """The point with its acceleration line lowered to KEEP_ACCEL of its fuel margin over the
    steady line (line: the engine's running line), with the frozen-speed figures there."""
    g_ss, steady = steady_at_speed(model, point.n_pct, line)
    g = g_ss + KEEP_ACCEL * (point.accel_fuel_kg_s - g_ss)
    x = frozen_state(model, steady.x, g)
    return replace(
        point,
        accel_fuel_kg_s=g,
        accel_v=pump_voltage_for(model, x, g),
        accel_limited_by="keep",
        accel_egt_k=_stations(model, x, g).t5,
        accel_surge_margin=surge_margin(model, x),
        accel_rate_pct_s=float(_rates(model, x, g)[3]),
    )


def fleet_point(
    model: EngineModel,
    line: dict[str, np.ndarray],
    nominal: SchedulePoint,
    corners: list[SchedulePoint],
) -> SchedulePoint:
    """The nominal point with the lowest acceleration line and the highest deceleration floor of
    the nominal engine and its corners (with the EGT, surge margin, fuel-air ratio and floor rate
    of the engine that sets each); the line no lower than the nominal's kept point (kept_point);
    its rate, and the acceleration schedule, the nominal engine's on that line."""
    acc = min([nominal, *corners], key=lambda p: p.accel_v)
    dec = max([nominal, *corners], key=lambda p: p.decel_v)
    rate = nominal.accel_rate_pct_s
    if acc is not nominal:
        kept = kept_point(model, line, nominal)
        acc = kept if kept.accel_v > acc.accel_v else acc
        rate = rate_at_voltage(model, line, nominal, acc.accel_v)
    return replace(
        nominal,
        accel_fuel_kg_s=acc.accel_fuel_kg_s,
        accel_v=acc.accel_v,
        accel_limited_by=acc.accel_limited_by,
        accel_egt_k=acc.accel_egt_k,
        accel_surge_margin=acc.accel_surge_margin,
        accel_rate_pct_s=rate,
        decel_fuel_kg_s=dec.decel_fuel_kg_s,
        decel_v=dec.decel_v,
        decel_far=dec.decel_far,
        decel_rate_pct_s=dec.decel_rate_pct_s,
        ndot_pct_s=allowed_rate(rate),
    )


def corner_schedules(
    model: EngineModel,
    speeds_pct: tuple[float, ...] = SPEEDS_PCT,
    spread: float = HEALTH_SPREAD,
    egt_limit_k: float = EGT_LIMIT_K,
    surge_margin_min: float = SURGE_MARGIN,
    lean_margin: float = LEAN_MARGIN,
    progress: Callable[[int, int], None] | None = None,
) -> list[tuple[dict[str, np.ndarray], list[SchedulePoint]]]:
    """Each corner of the health spread with its own running line and its own schedule points,
    rising: only the speeds it runs at within the limits (over a limit in steady state there,
    its EGT loop holds it lower)."""
    limits = (egt_limit_k, surge_margin_min, lean_margin)
    engines = health_corners(model, spread) if spread > 0.0 else []
    out = []
    for k, corner in enumerate(engines):
        own_line = running_line(corner)
        points = []
        for n in sorted(speeds_pct):
            if n < own_line["N_pct"][0]:
                continue  # slower than this engine runs
            try:
                points.append(schedule_point(corner, n, own_line, *limits))
            except ScheduleError:
                continue
        out.append((own_line, points))
        if progress is not None:
            progress(k + 1, len(engines))
    return out


def fleet_schedule(
    model: EngineModel,
    speeds_pct: tuple[float, ...] = SPEEDS_PCT,
    spread: float = HEALTH_SPREAD,
    egt_limit_k: float = EGT_LIMIT_K,
    surge_margin_min: float = SURGE_MARGIN,
    lean_margin: float = LEAN_MARGIN,
    progress: Callable[[int, int], None] | None = None,
    corners: list[tuple[dict[str, np.ndarray], list[SchedulePoint]]] | None = None,
) -> list[SchedulePoint]:
    """The schedule that holds for the nominal engine and every corner of the health spread
    (the nominal engine's alone with spread 0); corners: corner_schedules' result, when the
    caller has it already."""
    limits = (egt_limit_k, surge_margin_min, lean_margin)
    if corners is None:
        corners = corner_schedules(model, speeds_pct, spread, *limits, progress)
    line = running_line(model)
    nominal = [schedule_point(model, n, line, *limits) for n in sorted(speeds_pct)]
    at_speed: dict[float, list[SchedulePoint]] = {p.n_pct: [] for p in nominal}
    for _, points in corners:
        for p in points:
            at_speed[p.n_pct].append(p)
    return [fleet_point(model, line, p, at_speed[p.n_pct]) for p in nominal]


def line_rise_s(
    points: list[SchedulePoint], line: dict[str, np.ndarray], idle_pct: float = IDLE_PCT
) -> float:
    """The fastest acceleration the line allows the nominal engine: the time from steady idle to
    95 % of the thrust change up to the schedule's highest speed, along the line's shaft
    acceleration (frozen speed, interpolated between the points: the shaft's inertia, the gas
    path's lags neglected). line: the engine's running line; inf if the line stalls on the way."""
    n = np.array([p.n_pct for p in points])
    rate = np.array([p.accel_rate_pct_s for p in points])
    grid = np.linspace(idle_pct, n[-1], 2001)
    thrust = np.interp(grid, line["N_pct"], line["thrust_N"])
    target = thrust[0] + THRUST_FRACTION * (thrust[-1] - thrust[0])
    way = grid[: int(np.argmax(thrust >= target)) + 1]
    way = np.union1d(way, n[(n > way[0]) & (n < way[-1])])  # every point of the table on the way
    r = np.interp(way, n, rate)
    if np.any(r <= 0.0):
        return math.inf
    return float(np.trapezoid(1.0 / r, way))


def zero_fuel_egt_k(point: SchedulePoint, pump_dead_v: float) -> float:
    """The EGT at no fuel on the frozen-speed line through the point's steady state and its
    acceleration line (the gas rises linearly with the fuel there, so with the pump's voltage
    over its dead voltage): the intercept the ECU's EGT line takes (egt_zero_fuel_k)."""
    slope = (point.accel_egt_k - point.steady_egt_k) / (point.accel_v - point.steady_v)
    return point.steady_egt_k - slope * (point.steady_v - pump_dead_v)


def write_csv(points: list[SchedulePoint], path: Path) -> None:
    names = list(asdict(points[0]))
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(names)
        for pt in points:
            w.writerow([f"{v:.6g}" if isinstance(v, float) else v for v in asdict(pt).values()])


def write_json(points: list[SchedulePoint], settings: dict, path: Path) -> None:
    path.write_text(
        strict_json.dumps({"settings": settings, "points": [asdict(p) for p in points]}, indent=2)
        + "\n"
    )


def plot(points: list[SchedulePoint], settings: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = [p.n_pct for p in points]
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.5))
    for a, key, unit, scale in (
        (ax[0], "fuel_kg_s", "fuel flow [g/s]", 1e3),
        (ax[1], "v", "pump voltage [V]", 1.0),
    ):
        a.plot(
            n,
            [getattr(p, f"accel_{key}") * scale for p in points],
            "r-o",
            label="acceleration line",
        )
        a.plot(n, [getattr(p, f"steady_{key}") * scale for p in points], "k-o", label="steady line")
        a.plot(
            n,
            [getattr(p, f"decel_{key}") * scale for p in points],
            "b-o",
            label="deceleration floor",
        )
        a.set_xlabel("shaft speed [%N]")
        a.set_ylabel(unit)
        a.grid(True)
        a.legend()
    ax[2].plot(n, [p.accel_rate_pct_s for p in points], "r-o", label="on the acceleration line")
    ax[2].plot(n, [p.decel_rate_pct_s for p in points], "b-o", label="on the deceleration floor")
    ax[2].plot(n, [p.ndot_pct_s for p in points], "m--s", label="acceleration schedule (allowed)")
    ax[2].axhline(0.0, color="k", lw=0.8)
    ax[2].set_xlabel("shaft speed [%N]")
    ax[2].set_ylabel("shaft acceleration at frozen speed [%N/s]")
    ax[2].grid(True)
    ax[2].legend()
    fleet = settings.get("health_spread", 0.0)
    fig.suptitle(
        f"Fuel schedules: EGT <= {settings['egt_limit_k']:g} K, surge margin >= "
        f"{settings['surge_margin']:.0%}, lean blow-out margin {settings['lean_margin']:.0%}"
        + (f", for every engine within +-{fleet:.0%} health" if fleet else "")
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
