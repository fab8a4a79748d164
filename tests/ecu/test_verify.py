"""Verification against the document (sec. 4.2, 5.2) with the eq. 3.24 plant, in one process,
in both readings of the document (ecu.params.READINGS).

Module-scoped runs feed the tests: the fixed-point kernels on the true state and their float64
twin, the whole firmware and its twin on whole-rpm speed. The expectations are independent of
the code under test: the published numbers, the reproducing reading's figures and the printed
set-up's predictions of an independent integration (docs/errata.md), and a continuous-time
integration written here.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from ecu.params import READING_B0, firmware_convention, preset
from sil import verify
from sil.cli import main
from sil.verify import fast

REF = Path(__file__).resolve().parents[3] / "shared" / "reference" / "thesis_reference.json"
# the reproducing reading's sec. 5.2 results of an independent float64 integration (continuous
# time; thesis_errata.md), Theta_f and K_f by their regressors
ERRATA_5_2_REPRODUCING = {
    "lam": 4.8184, "ap21": -1.8057, "ap22": -2.3355, "kx1": -4.8137, "kx2": -1.5906,
    "kr": 5.1884, "kf_dn2dv": -0.00089, "kf_dndv": 0.03821,
}  # fmt: skip


@pytest.fixture(scope="module")
def runs() -> dict:
    """(scenario, reading) -> (fixed-point core on true state, its float64 twin)."""
    out = {}
    for key in fast.SETUPS:
        p = fast.scenario_params(*key)
        secs = 300.0
        out[key] = (fast.run_core(p, secs), fast.run_float(p, secs, true_rate=True))
    return out


def test_published_constants_match_the_reference_file() -> None:
    ref = json.loads(REF.read_text())
    s42 = ref["online_estimation_on_fast_model_sec_4_2"]["final"]
    s52 = ref["indirect_mrac_on_fast_model_sec_5_2"]["final"]
    for name, final in (("sec4_2", s42), ("sec5_2", s52)):
        pub = verify.PUBLISHED[name]
        assert [pub["ap21"], pub["ap22"]] == final["Ap_row2"]
        assert pub["lam"] == final["Lambda"]
        assert [pub["th_dndv"], pub["th_dn2dv"]] == final["Theta_row2"]
    assert [verify.PUBLISHED["sec5_2"][k] for k in ("kx1", "kx2")] == s52["Kx"]
    assert verify.PUBLISHED["sec5_2"]["kr"] == s52["Kr"]
    assert [verify.PUBLISHED["sec5_2"][k] for k in ("kf_dn2dv", "kf_dndv")] == s52["Kf"]


def _rel(a: float, b: float) -> float:
    return abs(a - b) / abs(b)


def test_reproducing_presets_hold_the_printed_values() -> None:
    """The reading changes how the printed numbers are read, not the numbers."""
    for name in ("sec4_2_estimator", "sec5_2_mrac_fast"):
        printed, reproducing = preset(name), preset(f"{name}_reproducing")
        assert printed.reading == "printed" and reproducing.reading == "reproducing"
        assert printed == preset(f"{name}_reproducing", reading="printed")


def test_firmware_convention_of_the_reproducing_reading() -> None:
    p = preset("sec5_2_mrac_fast_reproducing", init_kf=(0.1, 0.2), init_theta_row2=(0.3, 0.4))
    q = firmware_convention(p)
    assert q.reading == "printed"
    assert q.gamma_theta == (8.0, 0.004) and q.init_theta_row2 == (0.4, 0.3)
    assert q.init_kf == (0.2, 0.1)
    assert math.isclose(q.gamma_lambda, 0.017 * 4.822**2)
    assert math.isclose(q.gamma_x[0], 0.1 * READING_B0) and math.isclose(q.gamma_r, 0.1 * 4.822)
    assert q.init_lambda == p.init_lambda  # Lambda reported as b0 lambda: as printed
    assert firmware_convention(preset("sec5_2_mrac_fast")) == preset("sec5_2_mrac_fast")


@pytest.mark.parametrize("key", list(fast.SETUPS))
def test_fixed_point_core_follows_its_float64_twin(runs: dict, key: tuple[str, str]) -> None:
    core, twin = runs[key]
    assert math.sqrt(float(((core.n_pct - twin.n_pct) ** 2).mean())) < 0.05  # %N
    keys = ("ap21", "ap22", "lam") + (("kx1", "kx2", "kr") if key[0] == "sec5_2" else ())
    for k in keys:
        assert _rel(core.estimates[k], twin.estimates[k]) < verify.TWIN_TOL[key[0]], k


def test_sec_5_2_reproducing_reading_meets_the_independent_integration(runs: dict) -> None:
    for run in runs[("sec5_2", "reproducing")]:
        e = run.estimates
        for k in ("lam", "ap21", "ap22", "kx1", "kx2", "kr"):
            assert _rel(e[k], ERRATA_5_2_REPRODUCING[k]) < 0.005, k
        assert _rel(e["kf_dndv"], ERRATA_5_2_REPRODUCING["kf_dndv"]) < 0.03
        assert abs(e["kf_dn2dv"] - ERRATA_5_2_REPRODUCING["kf_dn2dv"]) < 1e-4


def test_sec_5_2_printed_reading_stays_below_the_bound(runs: dict) -> None:
    """V-dot = -2 zeta omega_n e2^2 bounds the change of Lambda-hat by 0.28 in this run
    (thesis_errata.md): the printed set-up cannot reach the published 4.819 from 4.3."""
    for run in runs[("sec5_2", "printed")]:
        assert run.estimates["lam"] < 4.3 + 0.28
        assert _rel(run.estimates["lam"], verify.PREDICTED_PRINTED["sec5_2"]["lam"]) < 0.005


def test_mrac_tracks_the_reference_model_and_meets_eq_5_14(runs: dict) -> None:
    for reading in fast.READINGS:
        core, _ = runs[("sec5_2", reading)]
        last = core.t >= core.t[-1] - verify.TRACKING_WINDOW_S
        track = math.sqrt(float(((core.n_pct[last] - core.nref_pct[last]) ** 2).mean()))
        assert track < verify.TRACKING_TOL_PCT
        # the reference model itself reaches the command (unit DC gain, eq. 5.19)
        assert abs(core.nref_pct[-1] - (89.68 - 1.0)) < 0.01
        # eq. 5.14: the gains satisfy the matching conditions with the current estimates
        e = core.estimates
        assert abs(e["ap21"] + 25.0 + e["lam"] * e["kx1"]) < 0.05
        assert abs(e["ap22"] + 10.0 + e["lam"] * e["kx2"]) < 0.05
        assert abs(-25.0 + e["lam"] * e["kr"]) < 0.05


def _continuous_sec_4_2(seconds: float, dt: float, reading: str) -> tuple[float, ...]:
    """Plant eq. 3.24 + identification model eq. 4.7 + laws eq. 4.31 as one ODE, RK4. In the
    reproducing reading the regressor is f = [dN^2 dV, dN dV] (eq. 3.10) against the printed
    Gamma_Theta, and Lambda = b0 lambda with lambda' = -Gamma_Lambda b0 e2 u."""
    th = (-1.8054, -2.3360, 4.8220, -0.1835, -0.0001)
    am21, am22 = -0.36, -1.2
    ga, gl, gt1, gt2 = 20.0, 3.0, 0.01, 100.0
    b0 = 4.822 if reading == "reproducing" else 1.0

    def f(t: float, s: list[float]) -> list[float]:
        x1, x2, xh1, xh2, a21, a22, lam, t1, t2 = s
        u = 1.0 if (t % 20.0) < 10.0 else -1.0
        f1, f2 = (x1 * x1 * u, x1 * u) if reading == "reproducing" else (x1 * u, x1 * x1 * u)
        e2 = xh2 - x2
        return [
            x2,
            th[0] * x1 + th[1] * x2 + (th[2] + th[3] * x1 + th[4] * x1 * x1) * u,
            xh2,
            am21 * xh1 + am22 * xh2 + (a21 - am21) * x1 + (a22 - am22) * x2 + lam * u
            + t1 * f1 + t2 * f2,
            -ga * x1 * e2, -ga * x2 * e2, -gl * b0 * b0 * u * e2, -gt1 * f1 * e2, -gt2 * f2 * e2,
        ]  # fmt: skip

    s = [0.0, 0.0, 0.0, 0.0, -1.0, -2.0, 0.5, 0.0, 0.0]
    t = 0.0
    for _ in range(round(seconds / dt)):
        k1 = f(t, s)
        k2 = f(t + dt / 2, [a + dt / 2 * b for a, b in zip(s, k1, strict=True)])
        k3 = f(t + dt / 2, [a + dt / 2 * b for a, b in zip(s, k2, strict=True)])
        k4 = f(t + dt, [a + dt * b for a, b in zip(s, k3, strict=True)])
        s = [a + dt / 6 * (b + 2 * c + 2 * d + e)
             for a, b, c, d, e in zip(s, k1, k2, k3, k4, strict=True)]  # fmt: skip
        t += dt
    return tuple(s[4:])


@pytest.mark.parametrize("reading", fast.READINGS)
def test_continuous_time_reference_agrees_with_the_twin(reading: str) -> None:
    """The discretised twin (true rate, as in the document) against the continuous equations,
    written here independently, in both readings."""
    p = fast.scenario_params("sec4_2", reading)
    tw = fast.run_float(p, 30.0, true_rate=True).estimates
    a21, a22, lam, _, _ = _continuous_sec_4_2(30.0, 0.002, reading)
    assert _rel(tw["lam"], lam) < 0.02
    assert abs(tw["ap21"] - a21) < 0.1 and abs(tw["ap22"] - a22) < 0.1
    if reading == "printed":
        assert lam < 1.2  # far from 4.821 after 30 s: slow convergence is in the equations


@pytest.mark.slow
def test_printed_sec_4_2_prediction_is_the_continuous_equations() -> None:
    """thesis_errata.md's as-printed sec. 4.2 values at 300 s, recomputed here."""
    a21, a22, lam, _, _ = _continuous_sec_4_2(300.0, 0.001, "printed")
    pred = verify.PREDICTED_PRINTED["sec4_2"]
    assert _rel(a21, pred["ap21"]) < 0.02 and _rel(a22, pred["ap22"]) < 0.03
    assert _rel(lam, pred["lam"]) < 0.005


def test_sil_verify_json_rows(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["verify", "--json", "--seconds", "10"])
    rows = json.loads(capsys.readouterr().out)
    assert code == (0 if all(r["ok"] for r in rows) else 1)
    keys = {"name", "source", "reading", "published", "predicted", "reached", "tolerance", "ok"}
    assert keys <= set(rows[0])
    names = {(r["name"], r["reading"]) for r in rows}
    assert ("sec 4.2 Lambda-hat", "reproducing") in names
    assert ("sec 5.2 K_r", "printed") in names
    printed = [r for r in rows if r["reading"] == "printed" and r["predicted"] is not None]
    assert printed and all("cannot reach" in r["note"] for r in printed)


def test_sil_verify_refuses_a_bad_duration(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["verify", "--seconds", "nan"]) == 2
    assert "--seconds" in capsys.readouterr().err
