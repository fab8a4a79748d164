"""Small things a user meets: help texts that state the true defaults, a first C build that
says what it does, the EGT plot with the ECU's limit."""

from __future__ import annotations

import numpy as np

from ecu.port import build
from sil import plots
from sil.cli import main


def test_demo_help_states_its_own_output_folder(capsys) -> None:
    try:
        main(["demo", "--help"])
    except SystemExit:
        pass
    out = " ".join(capsys.readouterr().out.split())
    assert "--out DIR output folder (default: out/demo, a folder per controller inside" in out


def test_the_first_c_build_says_what_it_is_doing(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(build, "BUILD_DIR", tmp_path)
    library = build.host_library()
    err = capsys.readouterr().err
    assert "ecu.port: compiling libecu_port.so with" in err and str(tmp_path) in err
    assert build.host_library() == library  # built once: the second call says nothing
    assert capsys.readouterr().err == ""


def test_egt_plot_draws_the_ecus_limit(tmp_path, monkeypatch) -> None:
    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig) or path)
    t = np.linspace(0.0, 10.0, 101)
    trace = {"time": t, "EGT": 1000 + t, "T4": 1100 + t, "LoopOwner": np.zeros_like(t)}
    plots.egt_plot(trace, "test", tmp_path / "egt.png", 1280.0)
    (ax,) = figures[0].axes
    limit = [line for line in ax.get_lines() if line.get_label() == "ECU's EGT limit 1280 K"]
    assert len(limit) == 1 and set(limit[0].get_ydata()) == {1280.0}
