"""Offline identification recovers known models; readers and the CLI handle bad input."""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from plant.fast_model import THETA_EQ_3_23, FastEngine
from sil.analysis import identify as ident

TRIM = ident.Trim(89.68, 5.0)


def _eq_3_24_record(dt: float = 0.01, seconds: float = 200.0) -> ident.Recording:
    """Square and step voltage into the eq. 3.24 model (the document's own fast model)."""
    engine = FastEngine()
    t = np.arange(0, seconds, dt)
    dv = np.where((t // 10) % 2 == 0, 1.0, -1.0) + np.where(t > seconds / 2, 1.0, 0.0)
    n = np.empty_like(t)
    for k, u in enumerate(dv):
        n[k] = engine.n_pct
        engine.step(float(u), dt)
    return ident.Recording(t, n, dv + TRIM.v, "eq-3.24")


def test_recovers_eq_3_23_from_clean_data():
    result = ident.identify(_eq_3_24_record(), trim=TRIM)
    np.testing.assert_allclose(result.theta[:4], THETA_EQ_3_23[:4], rtol=0.02)
    assert result.derived["omega_n"] == pytest.approx(1.3437, rel=0.02)
    assert result.derived["zeta"] == pytest.approx(0.8692, rel=0.02)
    assert ident.validate(result, _eq_3_24_record()) < 0.5


def test_noisy_10_hz_data_with_savitzky_golay():
    rec = _eq_3_24_record()
    rng = np.random.default_rng(42)
    noisy = ident.Recording(
        rec.t[::10], rec.n_pct[::10] + rng.normal(0, 0.05, 2000), rec.v[::10], "10 Hz"
    )
    result = ident.identify(noisy, trim=TRIM)
    np.testing.assert_allclose(result.theta[:3], THETA_EQ_3_23[:3], rtol=0.15)
    assert result.nrmse_pct < 2.0


def test_first_order_models_of_appendix_b():
    # dN' = -1/tau dN + a0/tau dV + a1/tau dN dV with the eq. B.9 parameters
    theta = np.array([-0.5662, 1.5632, -0.0628])
    t = np.arange(0, 120, 0.01)
    v = TRIM.v + np.where((t // 8) % 2 == 0, 1.0, -1.5)
    rec0 = ident.Recording(t, np.full_like(t, TRIM.n_pct), v, "B.4")
    n = ident.simulate(theta, "first", rec0, TRIM)
    result = ident.identify(ident.Recording(t, n, v, "B.4"), order="first", trim=TRIM)
    np.testing.assert_allclose(result.theta, theta, rtol=0.03)
    assert result.derived["tau"] == pytest.approx(1 / 0.5662, rel=0.03)
    quad = ident.identify(ident.Recording(t, n, v, "B.4"), order="first-quadratic", trim=TRIM)
    assert abs(quad.theta[3]) < 0.01  # no dN^2 dV term in the data


def _linear_record(order: str, gain: float, a: float, b: float = 0.0) -> ident.Recording:
    """A linear model's answer to voltage steps, integrated here independently of the tool:
    first order dN' = (K dV - dN) / tau (a = tau); second order dN'' = wn^2 (K dV - dN)
    - 2 zeta wn dN' (a = wn, b = zeta); Euler at 0.1 ms, sampled at 10 ms."""
    t = np.arange(0, 80, 0.01)
    dv = np.where((t // 7) % 2 == 0, 0.8, -0.6)
    n, n_dot, out = 0.0, 0.0, np.empty_like(t)
    for k, u in enumerate(dv):
        out[k] = n
        for _ in range(100):
            if order == "first-linear":
                n += 1e-4 * (gain * u - n) / a
            else:
                n_ddot = a * a * (gain * u - n) - 2 * b * a * n_dot
                n, n_dot = n + 1e-4 * n_dot, n_dot + 1e-4 * n_ddot
    return ident.Recording(t, TRIM.n_pct + out, TRIM.v + dv, order)


def test_linear_models_of_eq_3_1_and_appendix_b():
    first = ident.identify(
        _linear_record("first-linear", 1.85, 0.8), order="first-linear", trim=TRIM
    )
    assert first.derived["K"] == pytest.approx(1.85, rel=0.01)
    assert first.derived["tau"] == pytest.approx(0.8, rel=0.01)
    rec = _linear_record("second-linear", 2.2, 1.4, 0.85)
    second = ident.identify(rec, order="second-linear", trim=TRIM)
    assert second.derived["K"] == pytest.approx(2.2, rel=0.01)
    assert second.derived["omega_n"] == pytest.approx(1.4, rel=0.02)
    assert second.derived["zeta"] == pytest.approx(0.85, rel=0.02)
    assert second.nrmse_pct < 0.5
    with pytest.raises(ValueError, match="second-order model"):
        ident.ecu_commissioning(second)  # the ECU needs eq. 3.5's five parameters


def test_trim_estimate_and_window_errors():
    rec = _eq_3_24_record(seconds=20)
    assert ident.estimate_trim(rec).n_pct == pytest.approx(89.68 + 0.45, abs=0.5)
    with pytest.raises(ValueError, match="must be odd"):
        ident.derivatives(rec, 10)
    with pytest.raises(ValueError, match="too few"):
        ident.identify(rec.part(0, 0.0005))


def _write_csv(path, rec, speed_scale=1.0):
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", "speed", "volts"])
        for row in zip(rec.t, rec.n_pct * speed_scale, rec.v, strict=True):
            w.writerow(row)


def test_plain_csv_in_rpm_and_cli_export(tmp_path):
    rec = _eq_3_24_record()
    _write_csv(tmp_path / "bench.csv", rec, 1125.0)
    export = tmp_path / "commission.json"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "sil.cli",
            "identify",
            str(tmp_path / "bench.csv"),
            "--time-column",
            "t",
            "--speed-column",
            "speed",
            "--voltage-column",
            "volts",
            "--speed-unit",
            "rpm",
            "--trim-n",
            "89.68",
            "--trim-v",
            "5",
            "--export",
            str(export),
            "--out",
            str(tmp_path / "out"),
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["theta"][0] == pytest.approx(-1.8054, rel=0.05)
    assert report["nrmse_pct"] < 1.0
    commissioning = json.loads(export.read_text())
    assert commissioning["Lambda"] == pytest.approx(4.822, rel=0.05)
    assert (tmp_path / "out" / "identify.png").stat().st_size > 10_000


def test_bad_csv_names_file_and_line(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("t,speed,volts\n0,90,5\n0.1,abc,5\n")
    with pytest.raises(ValueError, match=r"bad.csv, line 3"):
        ident.read_csv(path, "t", "speed", "volts")
    with pytest.raises(ValueError, match="no column 'rpm'"):
        ident.read_csv(path, "t", "rpm", "volts")
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "sil.cli",
            "identify",
            str(path),
            "--time-column",
            "t",
            "--speed-column",
            "speed",
            "--voltage-column",
            "volts",
        ],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2 and "bad.csv, line 3" in result.stderr


def _identify_cli(path, *args: str) -> subprocess.CompletedProcess:
    columns = ("--time-column", "t", "--speed-column", "speed", "--voltage-column", "volts")
    return subprocess.run(
        [sys.executable, "-m", "sil.cli", "identify", str(path), *columns, *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_export_refuses_a_file_the_ecu_would_refuse(tmp_path):
    refusal = ident.commissioning_refusal(
        {**_commissioning_of_eq_3_23(), "trim_N_pct": -5.0, "trim_V": -12.0}
    )
    assert refusal is not None and refusal.startswith("field 'trim_N_pct': trim_n_pct=-5.0")
    assert ident.commissioning_refusal(_commissioning_of_eq_3_23()) is None
    _write_csv(tmp_path / "bench.csv", _eq_3_24_record(seconds=60))
    export = tmp_path / "commission.json"
    result = _identify_cli(
        tmp_path / "bench.csv", "--trim-n", "89.68", "--trim-v", "25", "--export", str(export)
    )
    assert result.returncode == 2, result.stderr
    assert f"--export {export}: the ECU would refuse" in result.stderr
    assert "(field '" in result.stderr and result.stderr.count("\n") == 1
    assert not export.exists()


def _commissioning_of_eq_3_23() -> dict:
    result = ident.Identification("second", list(THETA_EQ_3_23), TRIM, 7, {})
    return ident.ecu_commissioning(result)


def test_a_fit_outside_the_running_range_is_not_trusted_unless_forced(tmp_path):
    low, high = ident.running_range()
    rec = _eq_3_24_record(seconds=60)
    speed = rec.n_pct.copy()
    speed[-50:] = low - 10.0  # the engine stopped at the end of the recording
    _write_csv(tmp_path / "low.csv", ident.Recording(rec.t, speed, rec.v, "low"))
    export = tmp_path / "commission.json"
    trim = ("--trim-n", "89.68", "--trim-v", "5")
    result = _identify_cli(tmp_path / "low.csv", *trim, "--export", str(export), "--json")
    assert result.returncode == 1, result.stderr
    assert "not trusted" in result.stderr and f"running range {low:g}..{high:g} %N" in result.stderr
    assert json.loads(result.stdout)["trusted"] is False and not export.exists()
    forced = _identify_cli(tmp_path / "low.csv", *trim, "--export", str(export), "--force")
    assert forced.returncode == 0, forced.stderr
    assert "warning: exported a fit that is not trusted" in forced.stderr and export.exists()


def test_a_large_fit_error_is_not_trusted():
    result = ident.identify(_eq_3_24_record(seconds=60), trim=TRIM)
    assert ident.distrust(result, []) == []
    result.nrmse_pct = ident.MAX_NRMSE_PCT * 1.5
    assert ident.distrust(result, []) == ["fit error (NRMSE) 15.0 %, above 10 %"]
    result.nrmse_pct = float("inf")
    assert "diverging" in ident.distrust(result, [])[0]


def test_a_trim_point_too_far_from_the_data_is_refused_before_least_squares():
    with pytest.raises(ValueError, match="too far from the recorded speed and voltage"):
        ident.identify(_eq_3_24_record(seconds=20), trim=ident.Trim(1e300, 5.0))
