"""`sil bench control` and the smoothness figures it is built on: a known swing read back by
sil.metrics.command_smoothness, and the bench's runs against what they must show."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from sil import metrics


@pytest.mark.parametrize(("amplitude", "hz"), [(0.5, 8.5), (0.02, 1.0)])
def test_a_sine_on_the_command_reads_back(amplitude: float, hz: float) -> None:
    t = np.arange(0.0, 12.0, 0.01)
    v = 12.0 + amplitude * np.sin(2.0 * np.pi * hz * t)
    t4 = np.where(np.arange(t.size) % 2 == 0, 1150.0 + 40.0 * amplitude * np.sin(t), np.nan)
    got = metrics.command_smoothness({"time": t, "PumpVoltageTarget": v, "T4": t4}, 3.0, 9.5)
    assert got["pump_v_std"] == pytest.approx(amplitude / np.sqrt(2.0), rel=0.02)
    assert got["pump_v_p2p"] == pytest.approx(2.0 * amplitude, rel=0.02)
    assert got["pump_v_step_mean"] == pytest.approx(4.0 * amplitude * hz * 0.01, rel=0.05)
    assert got["pump_v_peak_hz"] == pytest.approx(hz, abs=0.16)  # 1 / 6.5 s resolution
    assert got["t4_p2p_K"] == pytest.approx(80.0 * amplitude, rel=0.05)


def test_the_bench_shows_the_limit_cycle_and_its_trade() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "sil.cli", "bench", "control", "--quick", "--json"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    f = json.loads(done.stdout)
    # without any sensor noise the MRAC's command still swings: its own limit cycle, fast
    assert f["mrac_noise_free_pump_v_std"] > 0.1
    assert 4.0 < f["mrac_noise_free_pump_v_peak_hz"] < 20.0
    # the plant's shaft answers the pump at once; the fast model's rate rolls off
    assert f["plant_rate_per_v_50_rad_s"] > 10.0 * f["fast_model_rate_per_v_50_rad_s"]
    # the PI, without rate feedback, is smooth; a gentler MRAC is smoother and tracks worse
    assert f["pi_pump_v_std"] < 0.25 * f["mrac_pump_v_std"]
    gentle = "mrac_wn3_z0.7_rf6"
    assert f[f"{gentle}_pump_v_std"] < 0.25 * f["mrac_pump_v_std"]
    assert f[f"{gentle}_tracking_rms_pct"] > f["mrac_tracking_rms_pct"]
    assert set(f["targets_met"]) == {"mrac_std", "mrac_t4", "mrac_rms"}
