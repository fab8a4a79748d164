"""`sil bench control` and the smoothness figures it is built on: a known swing read back by
sil.analysis.metrics.command_smoothness, and the bench's runs against what they must show."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from ecu.params import EcuParams
from sil.analysis import metrics


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


def test_the_bench_shows_the_limit_cycle_and_its_cure() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "sil.cli", "bench", "control", "--quick", "--json"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    f = json.loads(done.stdout)
    # the plant's shaft answers the pump at once; the fast model's rate rolls off
    assert f["plant_rate_per_v_50_rad_s"] > 10.0 * f["fast_model_rate_per_v_50_rad_s"]
    assert f["matching_lag_s"] == pytest.approx(EcuParams().mrac_cmd_lag_s, abs=0.02)
    # without the lag, and without any sensor noise, the MRAC's command swings: a limit cycle
    assert f["mrac_no_lag_noise_free_pump_v_std"] > 0.1
    assert 4.0 < f["mrac_no_lag_noise_free_pump_v_peak_hz"] < 20.0
    # with it the command is smooth and the tracking no worse
    assert f["mrac_pump_v_std"] < 0.2 * f["mrac_no_lag_pump_v_std"]
    assert f["mrac_t4_p2p_K"] < 0.2 * f["mrac_no_lag_t4_p2p_K"]
    assert f["mrac_tracking_rms_pct"] <= f["mrac_no_lag_tracking_rms_pct"]
    # the PI, without rate feedback, is smooth too and tracks the reference model far less closely
    assert f["pi_pump_v_std"] < 0.25 * f["mrac_no_lag_pump_v_std"]
    assert f["pi_tracking_rms_pct"] > 3.0 * f["mrac_tracking_rms_pct"]
    # a transient EGT allowance lets the step to 100 %N follow the reference model (the gas is
    # held at the limit without one), and the command at constant demand is untouched
    assert f["mrac_egt_allowance_40_K_tracking_rms_pct"] < 0.8 * f["mrac_tracking_rms_pct"]
    assert f["mrac_egt_allowance_40_K_pump_v_std"] == pytest.approx(f["mrac_pump_v_std"], rel=0.1)
    # the EGT loop joining the selection at 100 K instead of 50 K: the step to 100 %N rises under
    # its cap, and at 100 %N (about 25 K under the limit) it holds the engine under its demand
    assert f["mrac_egt_engage_100_K_tracking_rms_pct"] > 1.2 * f["mrac_tracking_rms_pct"]
    assert set(f["targets_met"]) == {"mrac_std", "mrac_t4", "mrac_rms"}
