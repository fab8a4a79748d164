"""The running line: steady states over the fuel range, as a table, a CSV and figures like the
document's figs. 2.10-2.13 (P3, EGT, fuel flow and thrust against shaft speed), with the AMT
Olympus specification points marked."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from plant.engine import EngineModel
from plant.trim import SteadyState, solve_steady, steady_line

COLUMNS = (
    "fuel_kg_s",
    "N_pct",
    "N_rpm",
    "P3_Pa",
    "P5_Pa",
    "T4_K",
    "EGT_K",
    "thrust_N",
    "air_kg_s",
    "flags",
)
# appendix A / thesis_reference.json engine_spec_amt_olympus
OLYMPUS_SPEC = {
    "max_speed_rpm": 112500.0,
    "pressure_ratio": 4.0,
    "mass_flow_kg_s": 0.4,
    "max_thrust_N": 190.0,
    "nominal_egt_K": 923.0,
    "max_egt_K": 973.0,
    "max_fuel_kg_s": 0.4 / 60.0,
}
TRIM_FUEL_KG_S = 0.008
DEFAULT_FUEL_KG_S = np.round(np.arange(0.0015, 0.0125001, 0.0005), 6)


def running_line(
    model: EngineModel, fuel_kg_s: np.ndarray = DEFAULT_FUEL_KG_S
) -> dict[str, np.ndarray]:
    """Steady states at each fuel flow, continued outwards from the eq. 2.32 trim; downwards as
    far as the engine keeps running (a weak engine's line ends at its slowest steady state)."""
    fuel = np.sort(np.asarray(fuel_kg_s, dtype=float))
    trim = solve_steady(model, TRIM_FUEL_KG_S)
    down: list[SteadyState] = []
    for g in fuel[fuel < TRIM_FUEL_KG_S][::-1]:
        try:
            down += steady_line(model, np.array([g]), start=down[-1] if down else trim)
        except ValueError:  # no running engine at this fuel flow, nor at any lower
            break
    down.reverse()
    up = steady_line(model, fuel[fuel >= TRIM_FUEL_KG_S], start=trim)
    rows = [_row(model, s) for s in down + up]
    return {c: np.array([r[i] for r in rows]) for i, c in enumerate(COLUMNS)}


def _row(model: EngineModel, s: SteadyState) -> tuple[float, ...]:
    st = s.stations
    return (
        st.g_fuel,
        s.x[3],
        s.x[3] * 0.01 * model.params.n_max_rpm,
        s.x[0],
        s.x[1],
        s.x[2],
        st.t5,
        st.thrust,
        st.g2,
        float(st.flags),
    )


def write_csv(table: dict[str, np.ndarray], path: Path) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for i in range(len(table["N_pct"])):
            w.writerow([f"{table[c][i]:.9g}" for c in COLUMNS])


def plot(table: dict[str, np.ndarray], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    spec = OLYMPUS_SPEC
    n = table["N_rpm"] / 1000.0
    n_spec = spec["max_speed_rpm"] / 1000.0
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    panels = [
        (
            ax[0, 0],
            table["P3_Pa"] / 1e5,
            "compressor outlet pressure P3, bar (fig. 2.10)",
            [(spec["pressure_ratio"] * 1.01325, "spec: PR 4 at max speed")],
        ),
        (
            ax[0, 1],
            table["EGT_K"],
            "EGT, K (fig. 2.11)",
            [(spec["nominal_egt_K"], "spec: nominal EGT"), (spec["max_egt_K"], "spec: max EGT")],
        ),
        (
            ax[1, 0],
            table["fuel_kg_s"] * 1e3,
            "fuel flow, g/s (fig. 2.12)",
            [(spec["max_fuel_kg_s"] * 1e3, "spec: max fuel 0.4 kg/min")],
        ),
        (
            ax[1, 1],
            table["thrust_N"],
            "thrust, N (fig. 2.13)",
            [(spec["max_thrust_N"], "spec: max thrust")],
        ),
    ]
    trim = int(np.argmin(np.abs(table["fuel_kg_s"] - TRIM_FUEL_KG_S)))
    for a, y, title, marks in panels:
        a.plot(n, y, "b.-", label="model running line")
        a.plot(n[trim], y[trim], "go", label="trim, eq. 2.32")
        for value, label in marks:
            a.plot(n_spec, value, "r*", ms=11)
            a.annotate(
                label,
                (n_spec, value),
                textcoords="offset points",
                xytext=(-110, 6),
                fontsize=8,
                color="r",
            )
        a.set(title=title, xlabel="shaft speed, krpm")
        a.grid(alpha=0.3)
    ax[0, 0].legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
