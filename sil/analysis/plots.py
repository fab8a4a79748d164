"""Plots of a run laid out like the document's figures (speed, pump, EGT, estimates, gains), and
for a run from rest the start and stop (speed, EGT, pump, starter and igniter, sequencer)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ecu import modes  # noqa: E402
from ecu import start_sequencer as seq  # noqa: E402
from sil.analysis.metrics import REST_PCT  # noqa: E402
from sil.record.results import write_with  # noqa: E402

_PANELS = {
    "estimates": (
        "Parameter estimates (figs. 4.6, 4.10)",
        [
            ("Est_Ap21", "A_p21 [1/s2]"),
            ("Est_Ap22", "A_p22 [1/s]"),
            ("Est_Lambda", "Lambda"),
            ("Est_Theta21", "Theta_f21"),
            ("Est_Theta22", "Theta_f22"),
        ],
    ),
    "gains": (
        "Controller gains (fig. 6.4)",
        [
            ("Gain_Kx1", "K_x1"),
            ("Gain_Kx2", "K_x2"),
            ("Gain_Kr", "K_r"),
            ("Gain_Kf1", "K_f1"),
            ("Gain_Kf2", "K_f2"),
        ],
    ),
}


def _save(fig, path: Path) -> Path:
    """Save the figure as ``path`` atomically (:func:`sil.record.results.write_with`: a full disk
    leaves no empty or partial PNG); WriteError names the file."""
    fig.tight_layout()
    try:
        return write_with(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    finally:
        plt.close(fig)


def speed_plot(trace: dict[str, np.ndarray], title: str, path: Path, open_loop: bool) -> Path:
    t = trace["time"]
    fig, (ax, ax2) = plt.subplots(
        2, 1, figsize=(10, 6.5), sharex=True, gridspec_kw={"height_ratios": [3, 1.3]}
    )
    if not open_loop:
        ax.plot(t, trace["command"], color="0.6", lw=1, label="speed command")
        ax.plot(
            t, trace["ReferenceSpeed"], "--", color="tab:green", lw=1.2, label="reference model"
        )
    ax.plot(t, trace["speed_true"], color="tab:blue", lw=1.2, label="engine (true)")
    ax.plot(t, trace["speed_meas"], color="tab:orange", lw=0.6, alpha=0.7, label="measured")
    ax.set_ylabel("shaft speed [%N_max]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax2.plot(t, trace["PumpVoltageTarget"], color="tab:red", lw=1, label="pump voltage")
    if open_loop:
        ax2.plot(t, trace["command"], "--", color="0.5", lw=1, label="voltage command")
    ax2.set_ylabel("pump [V]")
    ax2.set_xlabel("time [s]")
    ax2.grid(alpha=0.3)
    ax2.legend(loc="best", fontsize=8)
    return _save(fig, path)


def egt_plot(
    trace: dict[str, np.ndarray], title: str, path: Path, limit_k: float | None = None
) -> Path:
    t = trace["time"]
    fig, ax = plt.subplots(figsize=(10, 4))
    ax.plot(t, trace["EGT"], color="tab:red", lw=1, label="EGT (thermocouple)")
    ax.plot(t, trace["T4"], color="tab:purple", lw=0.8, alpha=0.7, label="T4 (truth)")
    if limit_k is not None:
        ax.axhline(limit_k, color="black", ls="--", lw=1, label=f"ECU's EGT limit {limit_k:g} K")
    limited = trace["LoopOwner"] == 1
    if limited.any():
        ax.fill_between(
            t,
            0,
            1,
            where=limited,
            transform=ax.get_xaxis_transform(),
            color="tab:red",
            alpha=0.12,
            label="EGT limiter owns the pump",
        )
    ax.set_ylabel("temperature [K]")
    ax.set_xlabel("time [s]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    return _save(fig, path)


def panel_plot(trace: dict[str, np.ndarray], kind: str, title: str, path: Path) -> Path:
    heading, signals = _PANELS[kind]
    t = trace["time"]
    fig, axes = plt.subplots(len(signals), 1, figsize=(10, 1.7 * len(signals)), sharex=True)
    for ax, (column, label) in zip(axes, signals, strict=True):
        ax.plot(t, trace[column], lw=1)
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_title(f"{title}: {heading}")
    axes[-1].set_xlabel("time [s]")
    return _save(fig, path)


def sequencer_states(trace: dict[str, np.ndarray]) -> np.ndarray:
    """The sequencer's state at every tick: EcuStarter's while the ECU sends it (ARMED,
    SHUTDOWN), RUN in RUN and OFF in OFF (the frame is not sent there and the trace holds it)."""
    mode = trace["ActuatorMode"]
    state = np.nan_to_num(trace["SequencerState"]).copy()
    state[mode == modes.RUN] = seq.RUN
    state[mode == modes.OFF] = seq.OFF
    return state


def start_plot(trace: dict[str, np.ndarray], title: str, path: Path) -> Path:
    """Speed, EGT, pump voltage, starter duty and igniter, and the sequencer's state."""
    t = trace["time"]
    fig, axes = plt.subplots(
        4, 1, figsize=(10, 9), sharex=True, gridspec_kw={"height_ratios": [2, 2, 1.5, 1.3]}
    )
    ax = axes[0]
    ax.plot(t, trace["command"], color="0.6", lw=1, label="speed demand")
    ax.plot(t, trace["speed_true"], color="tab:blue", lw=1.2, label="engine (true)")
    ax.set_ylabel("shaft speed [%N_max]")
    ax.set_title(f"{title}: start and stop")
    ax = axes[1]
    ax.plot(t, trace["EGT"], color="tab:red", lw=1, label="EGT (thermocouple)")
    ax.plot(t, trace["HotSectionTemp"], color="tab:brown", lw=1, label="hot section metal (truth)")
    ax.plot(t, trace["T4"], color="tab:purple", lw=0.6, alpha=0.6, label="T4 (truth)")
    ax.axhline(373.0, color="black", ls=":", lw=0.8, label="373 K")
    ax.set_ylabel("temperature [K]")
    ax = axes[2]
    ax.plot(t, trace["PumpVoltageTarget"], color="tab:red", lw=1, label="pump voltage [V]")
    ax.plot(t, 0.1 * trace["StarterDuty"], color="tab:green", lw=1, label="starter duty [10 %]")
    ignited = np.nan_to_num(trace["IgniterOn"]) > 0
    ax.fill_between(t, 0, 1, where=ignited, transform=ax.get_xaxis_transform(),
                    color="tab:orange", alpha=0.2, label="igniter on")  # fmt: skip
    ax.set_ylabel("pump, starter")
    ax = axes[3]
    ax.step(t, sequencer_states(trace), where="post", color="tab:blue", lw=1.2)
    ax.set_yticks(range(len(seq.NAMES)), seq.NAMES, fontsize=7)
    ax.set_xlabel("time [s]")
    for ax in axes:
        ax.grid(alpha=0.3)
    for ax in axes[:3]:
        ax.legend(loc="best", fontsize=7)
    return _save(fig, path)


def plot_run(
    trace: dict[str, np.ndarray],
    out_dir: Path,
    title: str,
    controller: str,
    egt_limit_k: float | None = None,
) -> list[Path]:
    """All plots of one run (the EGT with the ECU's limit, when given); the files written."""
    if len(trace["time"]) < 2:
        return []
    open_loop = controller == "open_loop"
    written = [
        speed_plot(trace, title, out_dir / "speed.png", open_loop),
        egt_plot(trace, title, out_dir / "egt.png", egt_limit_k),
    ]
    if np.isfinite(trace["Est_Lambda"]).any():
        written.append(panel_plot(trace, "estimates", title, out_dir / "estimates.png"))
    if controller == "mrac":
        written.append(panel_plot(trace, "gains", title, out_dir / "gains.png"))
    if trace["speed_true"][0] < REST_PCT and (trace["ActuatorMode"] == modes.ARMED).any():
        written.append(start_plot(trace, title, out_dir / "start.png"))
    return written
