"""The run plots: what each one draws."""

from __future__ import annotations

import numpy as np

from sil.analysis import plots


def test_egt_plot_draws_the_ecus_limit(tmp_path, monkeypatch) -> None:
    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig) or path)
    t = np.linspace(0.0, 10.0, 101)
    trace = {"time": t, "EGT": 1000 + t, "T4": 1100 + t, "LoopOwner": np.zeros_like(t)}
    plots.egt_plot(trace, "test", tmp_path / "egt.png", 1280.0)
    (ax,) = figures[0].axes
    limit = [line for line in ax.get_lines() if line.get_label() == "ECU's EGT limit 1280 K"]
    assert len(limit) == 1 and set(limit[0].get_ydata()) == {1280.0}
