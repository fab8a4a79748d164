"""Generate and calibrate the Olympus-class maps; write olympus_maps.npz, calibration.json, plots.

    python -m plant.maps.build

Shapes (n = corrected speed / N_max):
- compressor speed lines, eq. 2.7: from choke flow g_ch(n) at pressure ratio 1 down to
  0.7 g_ch(n) at the surge ratio beta_s(n) = 1 + (BETA_SURGE_100 - 1) n^2, cubic in between
  (negative slope everywhere, so the compressor plenum is stable), and a steep fall of flow beyond
  surge;
- compressor efficiency, eq. 2.8: a paraboloid around 0.85 g_ch(n), the same peak efficiency on
  every speed line from 70 % up, rising towards low speed (no Mach losses) by EFF_LOW_SPEED_RISE;
- turbine flow function, eq. 2.18: tanh in the expansion ratio (a nozzle guide vane that
  chokes), weakly falling with N/sqrt(T4);
- turbine efficiency, eq. 2.19: a parabola in the blade-to-jet speed ratio
  U/C ~ (N/sqrt(T4)) / sqrt(1 - beta_t^-0.25), 1 - TURB_EFF_CURVATURE (1 - v)^2 in
  v = (U/C) / (U/C)_opt, the trim at v = UC_TRIM_OVER_OPT (peak 0.92 once scaled to the trim);
- gear pump, sec. 2.2: displacement flow proportional to the voltage above a dead band, minus a
  leakage that rises linearly with outlet pressure, the leakage slope flattening as voltage rises.
Calibration: the trim of eq. 2.32 fixes, through the component equations of ch. 2, the flows,
the turbine efficiency and the nozzle area; each table is scaled so that its bilinear
interpolation returns exactly those values at the trim point, then refine() removes what the
components' own fixed-point passes on gamma leave over, so that eq. 2.32 is an equilibrium.
Dynamics: with the plenums, the burner and J fixed by the document, the shaft is the only slow
state; its time constant at constant pump voltage is J omega^2 / (-d(eta_m P_t - P_c)/d ln omega)
and its gain dN/dV = (dN/dg_f on the running line) (dg_f/dV of the pump). What the document
leaves open sets both, towards its appendix B fit over 90-94 %N (K 1.85 %N/V, tau 0.8 s): the
turbine efficiency's curvature (below the optimum U/C its efficiency rises with speed, which
lengthens tau, and falls as T4 rises, which takes power from a fuel step), the compressor's choke
flow exponent (fuel per %N along the running line) and the pump's flow per volt (both lower K).
The limits: EGT at 100 %N stays below the ECU's EGT limit, the pump voltage at 100 %N below its
v_max, a large fuel step still overspeeds the engine, and the running line reaches idle (below
45 %N at 1.5 g/s): the steeper turbine curve takes efficiency from the engine at low speed, which
the compressor's low-speed efficiency gives back (without it the engine hangs below 47 %N).
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from plant.aerothermal import make_model
from plant.engine import EngineParams, Stations, stations
from plant.intake import intake
from plant.maps import MAPS_DIR, MAPS_FILE, EngineMaps, load_maps, maps_from_arrays
from plant.nozzle import nozzle
from plant.pump import PumpTable
from plant.thermo import cp_air, gamma_mean
from protocol import strict_json

TRIM_FUEL = 0.008  # kg/s, eq. 2.33
TRIM_X = np.array([294845.0, 162676.0, 1159.0, 89.68])  # eq. 2.32
ETA_C_TRIM = 0.76  # chosen compressor efficiency at trim (small centrifugal stage)

BETA_SURGE_100 = 4.4  # surge pressure ratio at 100 % corrected speed
FLOW_EXPONENT = 1.45  # choke flow ~ n^FLOW_EXPONENT
SURGE_FLOW_FRACTION = 0.7
TURB_CHOKE_RATE = 1.9  # tanh slope of the turbine flow function
UC_TRIM_OVER_OPT = 0.6  # blade speed ratio at trim relative to the optimum
TURB_EFF_CURVATURE = 1.34  # turbine efficiency 1 - c (1 - v)^2, v = (U/C) / (U/C)_opt
EFF_LOW_SPEED_N = 0.7  # compressor peak efficiency constant above this corrected speed
EFF_LOW_SPEED_RISE = 0.06  # and rising linearly below it, by this much at zero speed

PUMP_FLOW_PER_VOLT = 0.74e-3  # kg/s per V above the dead band, at zero outlet pressure
PUMP_DEAD_BAND_V = 0.5
PUMP_LEAK_PER_PA = 4.0e-9  # kg/s per Pa at PUMP_LEAK_REF_V
PUMP_LEAK_REF_V = 6.0
PUMP_CURRENT = (0.25, 0.06, 4.0e-6)  # A, A/V, A/Pa (fig. 2.8: current rises with pressure)


def compressor_flow_shape(beta: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Corrected flow (unscaled: g_ch(1) = 1) on the grid beta x n."""
    b, nn = np.meshgrid(beta, n, indexing="ij")
    g_ch = nn**FLOW_EXPONENT
    beta_s = 1.0 + (BETA_SURGE_100 - 1.0) * nn**2
    r = (b - 1.0) / np.maximum(beta_s - 1.0, 1e-9)
    g = g_ch * (1.0 - (1.0 - SURGE_FLOW_FRACTION) * np.clip(r, -0.5, 1.0) ** 3)
    beyond = b > beta_s
    g_surge = SURGE_FLOW_FRACTION * g_ch
    g[beyond] = (g_surge - 2.0 * g_ch * (b - beta_s))[beyond]
    return np.maximum(g, 0.0)


def compressor_eff_shape(g: np.ndarray, n: np.ndarray, g_ch_100: float) -> np.ndarray:
    """Isentropic efficiency (unscaled) on the grid corrected flow x n."""
    gg, nn = np.meshgrid(g, n, indexing="ij")
    g_ch = np.maximum(g_ch_100 * nn**FLOW_EXPONENT, 0.02)
    peak = 0.80 + EFF_LOW_SPEED_RISE * np.maximum(EFF_LOW_SPEED_N - nn, 0.0) / EFF_LOW_SPEED_N
    return np.clip(peak - 2.0 * ((gg - 0.85 * g_ch) / g_ch) ** 2, 0.30, 0.85)


def turbine_flow_shape(beta: np.ndarray, n_t: np.ndarray, n_t_trim: float) -> np.ndarray:
    b, nt = np.meshgrid(beta, n_t, indexing="ij")
    return np.tanh(TURB_CHOKE_RATE * (b - 1.0)) * (1.03 - 0.03 * nt / n_t_trim)


def _uc(beta: np.ndarray, n_t: np.ndarray) -> np.ndarray:
    return n_t / np.sqrt(np.maximum(1.0 - beta**-0.25, 1e-6))


def turbine_eff_shape(
    beta: np.ndarray, n_t: np.ndarray, beta_trim: float, n_t_trim: float
) -> np.ndarray:
    b, nt = np.meshgrid(beta, n_t, indexing="ij")
    uc_opt = _uc(np.array(beta_trim), np.array(n_t_trim)) / UC_TRIM_OVER_OPT
    v = _uc(b, nt) / uc_opt
    return np.clip(1.0 - TURB_EFF_CURVATURE * (1.0 - v) ** 2, 0.20, 1.0)


def pump_flow_shape(voltage: np.ndarray, pressure: np.ndarray) -> np.ndarray:
    v, p = np.meshgrid(voltage, pressure, indexing="ij")
    leak = PUMP_LEAK_PER_PA * np.sqrt(PUMP_LEAK_REF_V / np.maximum(v, 1.0))
    return np.maximum(PUMP_FLOW_PER_VOLT * (v - PUMP_DEAD_BAND_V) - leak * p, 0.0)


def _scale_to(
    x_axis: np.ndarray, y_axis: np.ndarray, table: np.ndarray, x: float, y: float, target: float
) -> np.ndarray:
    from plant.lookup import interp2

    value, _ = interp2(x_axis, y_axis, table, x, y)
    return table * (target / value)


def trim_requirements() -> dict[str, float]:
    """What the component equations need at the eq. 2.32 trim for dx/dt = 0 (unscaled maps)."""
    p = EngineParams(nozzle_area_m2=1.0)
    p3, p5, t4, n_pct = TRIM_X
    p2, t2 = intake(p.p0_pa, p.t0_k, p.u0_m_s)
    beta_c = p3 / p2
    t3 = t2
    for _ in range(3):
        g = gamma_mean(t2, t3)
        t3 = t2 * (1.0 + (beta_c ** ((g - 1.0) / g) - 1.0) / ETA_C_TRIM)  # 2.10
    gf = TRIM_FUEL
    h_in = gf * (p.cp_fuel * p.t0_k + p.eta_b * p.lhv)
    g4 = (h_in - gf * cp_air(t3) * t3) / (cp_air(t4) * t4 - cp_air(t3) * t3)  # 2.15 = 0, 2.16
    g3 = g4 - gf
    pwr_c = g3 * (cp_air(t3) * t3 - cp_air(t2) * t2)  # 2.11
    pwr_t = pwr_c / p.eta_m  # 2.31 = 0
    h5 = cp_air(t4) * t4 - pwr_t / g4  # 2.21
    t5 = t4 * 0.9
    for _ in range(50):
        t5 -= (cp_air(t5) * t5 - h5) / (cp_air(t5) + 1e-3)
    p4 = p.eta_loss * p3
    beta_t = p4 / p5
    g = gamma_mean(t4, t5)
    eta_t = (1.0 - t5 / t4) / (1.0 - (1.0 / beta_t) ** ((g - 1.0) / g))  # 2.20
    g7_unit_area, _, _ = nozzle(p5, t5, p.p0_pa, p.u0_m_s, 1.0, p.eta_n)
    n_rpm = n_pct * 0.01 * p.n_max_rpm
    return {
        "beta_c": beta_c,
        "n_cor_pct": n_pct,
        "g2_cor": g3,
        "eta_c": ETA_C_TRIM,
        "T3_K": t3,
        "g4": g4,
        "T5_K": t5,
        "beta_t": beta_t,
        "n_t": n_rpm / math.sqrt(t4),
        "eta_t": eta_t,
        "phi_t": g4 * math.sqrt(t4) / p4,
        "nozzle_area_m2": g4 / g7_unit_area,
        "power_compressor_W": pwr_c,
        "power_turbine_W": pwr_t,
    }


def build() -> tuple[dict[str, np.ndarray], dict[str, float]]:
    req = trim_requirements()
    comp_beta = np.round(np.arange(0.8, 5.5001, 0.025), 6)
    comp_n = np.round(np.arange(0.0, 125.001, 2.5), 6)
    flow = compressor_flow_shape(comp_beta, comp_n / 100.0)
    flow = _scale_to(comp_beta, comp_n, flow, req["beta_c"], req["n_cor_pct"], req["g2_cor"])
    g_ch_100 = float(np.interp(1.0, comp_beta, flow[:, np.searchsorted(comp_n, 100.0)]))
    flow_axis = np.round(np.arange(0.0, 0.6001, 0.005), 6)
    eff = compressor_eff_shape(flow_axis, comp_n / 100.0, g_ch_100)
    eff = _scale_to(flow_axis, comp_n, eff, req["g2_cor"], req["n_cor_pct"], req["eta_c"])
    surge = 1.0 + (BETA_SURGE_100 - 1.0) * (comp_n / 100.0) ** 2

    turb_beta = np.round(np.arange(1.0, 3.5001, 0.02), 6)
    turb_nt = np.round(np.arange(0.0, 8000.001, 100.0), 6)
    tflow = turbine_flow_shape(turb_beta, turb_nt, req["n_t"])
    tflow = _scale_to(turb_beta, turb_nt, tflow, req["beta_t"], req["n_t"], req["phi_t"])
    teff = turbine_eff_shape(turb_beta, turb_nt, req["beta_t"], req["n_t"])
    teff = _scale_to(turb_beta, turb_nt, teff, req["beta_t"], req["n_t"], req["eta_t"])

    pump_v = np.round(np.arange(0.0, 24.001, 0.5), 6)
    pump_p = np.round(np.arange(0.0, 8.0001e5, 0.25e5), 6)
    pflow = pump_flow_shape(pump_v, pump_p)
    pump = PumpTable(pump_v, pump_p, pflow, *PUMP_CURRENT)
    p_out_trim = TRIM_X[0] + EngineParams(nozzle_area_m2=1.0).injector_dp_pa - 101325.0
    v_trim = _trim_voltage(pump, p_out_trim)

    arrays = {
        "comp_beta": comp_beta,
        "comp_n_cor_pct": comp_n,
        "comp_flow": flow,
        "comp_flow_axis": flow_axis,
        "comp_efficiency": eff,
        "comp_surge_beta": surge,
        "turb_beta": turb_beta,
        "turb_n_t": turb_nt,
        "turb_flow": tflow,
        "turb_efficiency": teff,
        "pump_voltage": pump_v,
        "pump_pressure": pump_p,
        "pump_flow": pflow,
        "pump_current": np.array(PUMP_CURRENT),
        "nozzle_area_m2": np.array([req["nozzle_area_m2"]]),
        "trim_pump_voltage": np.array([v_trim]),
    }
    refine(arrays)
    req["trim_pump_voltage"] = v_trim
    req["compressor_choke_flow_100pct_kg_s"] = g_ch_100
    req["nozzle_area_m2"] = float(arrays["nozzle_area_m2"][0])
    return arrays, req


def refine(arrays: dict[str, np.ndarray], iterations: int = 12) -> None:
    """Make the eq. 2.32 state an exact equilibrium of the compiled model (in place).

    trim_requirements() solves the balances with its own passes on gamma; the components take
    theirs, so a small residual remains. Each pass rescales, from the model's own station values
    at the trim: the turbine flow table so that the burner is at rest (eq. 2.15 = 0), the
    compressor flow table so that the compressor plenum is (eq. 2.12), the nozzle area for the
    jet-pipe plenum (eq. 2.22) and the turbine efficiency table for the shaft (eq. 2.31).
    """
    for _ in range(iterations):
        model = make_model(maps=maps_from_arrays(arrays))
        p = model.params
        st = Stations(*stations(TRIM_X, TRIM_FUEL, model))
        t3, t4 = st.t3, TRIM_X[2]
        h_in = TRIM_FUEL * (p.cp_fuel * p.t0_k + p.eta_b * p.lhv)
        g4 = (h_in - TRIM_FUEL * cp_air(t3) * t3) / (cp_air(t4) * t4 - cp_air(t3) * t3)
        arrays["turb_flow"] = arrays["turb_flow"] * (g4 / st.g4)
        arrays["comp_flow"] = arrays["comp_flow"] * ((g4 - TRIM_FUEL) / st.g2)
        arrays["nozzle_area_m2"] = arrays["nozzle_area_m2"] * (st.g4 / st.g6)
        arrays["turb_efficiency"] = arrays["turb_efficiency"] * (
            st.power_compressor / (p.eta_m * st.power_turbine)
        )


def _trim_voltage(pump: PumpTable, p_out_gauge: float) -> float:
    from plant.pump import pump_flow

    lo, hi = 0.0, float(pump.voltage[-1])
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if pump_flow(mid, p_out_gauge, pump, 1.0)[0] < TRIM_FUEL:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def plot(maps: EngineMaps) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c, t, p = maps.compressor, maps.turbine, maps.pump
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.5))
    for j, n in enumerate(c.n_cor_pct):
        if n >= 30 and n % 10 == 0:
            ok = c.beta <= c.surge_beta[j] + 1e-9
            ax[0].plot(c.flow[ok, j], c.beta[ok], "b-", lw=1)
            ax[0].annotate(f"{n:.0f}%", (c.flow[ok, j][-1], c.beta[ok][-1]), fontsize=7)
            ax[1].plot(c.flow_axis, c.efficiency[:, j], lw=1, label=f"{n:.0f}%")
    ax[0].plot(
        [np.interp(s, c.beta, c.flow[:, j]) for j, s in enumerate(c.surge_beta)],
        c.surge_beta,
        "r--",
        label="surge line",
    )
    ax[0].plot(0.4, 4.0, "k*", ms=10, label="Olympus spec 0.4 kg/s, PR 4")
    ax[0].set(
        xlabel="corrected flow, kg/s",
        ylabel="pressure ratio",
        title="compressor (eq. 2.7)",
        xlim=(0, 0.5),
        ylim=(1, 5),
    )
    ax[0].legend(fontsize=7)
    ax[1].set(
        xlabel="corrected flow, kg/s",
        ylabel="isentropic efficiency",
        title="compressor (eq. 2.8)",
        ylim=(0.3, 0.9),
        xlim=(0, 0.5),
    )
    ax[1].legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(MAPS_DIR / "compressor_map.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.5))
    for j, nt in enumerate(t.n_t):
        if 1000 <= nt <= 5000 and nt % 1000 == 0:
            ax[0].plot(t.beta, t.flow[:, j] * 1e5, lw=1, label=f"N/sqrt(T4) = {nt:.0f}")
            ax[1].plot(t.beta, t.efficiency[:, j], lw=1, label=f"{nt:.0f}")
    ax[0].set(
        xlabel="expansion ratio P4/P5",
        ylabel="g4 sqrt(T4)/P4 x 1e5",
        title="turbine flow (eq. 2.18)",
    )
    ax[1].set(
        xlabel="expansion ratio P4/P5",
        ylabel="isentropic efficiency",
        title="turbine efficiency (eq. 2.19), N/sqrt(T4) in rpm/sqrt(K)",
    )
    ax[0].legend(fontsize=7)
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(MAPS_DIR / "turbine_map.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    amps = ax.twinx()
    for v in (3.0, 6.0, 8.0, 10.0, 12.0):
        i = int(np.searchsorted(p.voltage, v))
        line = ax.plot(p.pressure / 1e5, p.flow[i, :] * 1e3, label=f"{v:.0f} V")[0]
        current = p.current_idle_a + p.current_per_volt * v + p.current_per_pa * p.pressure
        amps.plot(p.pressure / 1e5, current, "--", color=line.get_color())
    ax.set(
        xlabel="outlet gauge pressure, bar",
        ylabel="fuel flow, g/s (solid)",
        title="gear pump (sec. 2.2, cf. fig. 2.8)",
        ylim=(0, None),
    )
    amps.set(ylabel="pump current, A (dashed)", ylim=(0, None))
    ax.legend(loc="upper center")
    fig.tight_layout()
    fig.savefig(MAPS_DIR / "pump_map.png", dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-plots", action="store_true")
    args = ap.parse_args(argv)
    arrays, req = build()
    np.savez(MAPS_FILE, **arrays)
    maps = load_maps()
    model = make_model(maps=maps)
    x = TRIM_X.copy()
    dxdt = np.empty(4)
    from plant.engine import engine_rates

    engine_rates(x, TRIM_FUEL, 1.0, model, dxdt)
    req["trim_residual_dxdt"] = [float(v) for v in dxdt]
    st = stations(x, TRIM_FUEL, model)
    req["trim_thrust_N"] = float(st[9])
    req["trim_EGT_K"] = float(st[6])
    (MAPS_DIR / "calibration.json").write_text(strict_json.dumps(req, indent=2) + "\n")
    print(strict_json.dumps(req, indent=2))
    if not args.no_plots:
        plot(maps)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
