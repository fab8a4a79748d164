"""Verification against the document (sec. 4.2, 5.2) with the eq. 3.24 plant, in one process.

One module-scoped run of both 300 s scenarios (fixed, float twin, float twin with true rate)
feeds all tests here.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from sil import verify
from sil.cli import main

REF = Path(__file__).resolve().parents[3] / "shared" / "reference" / "thesis_reference.json"


@pytest.fixture(scope="module")
def runs() -> dict:
    out = {}
    for name in verify.SCENARIOS:
        p = verify.scenario_params(name)
        out[name] = (
            verify.run_fixed(p, 300.0),
            verify.run_float(p, 300.0, true_rate=False),
            verify.run_float(p, 300.0, true_rate=True),
        )
    return out


def test_published_constants_match_the_reference_file() -> None:
    ref = json.loads(REF.read_text())
    theta = ref["offline_ls_aero_thermal_eq_3_23"]["theta"]
    assert verify.PUBLISHED["ap_row2"] == (theta[0], theta[1])
    assert verify.PUBLISHED["lambda"] == theta[2]
    note = ref["indirect_mrac_on_fast_model_sec_5_2"]["note"]
    assert "[-4.809, -1.589]" in note and "5.185" in note
    assert tuple(verify.PUBLISHED["kx_ideal"]) == (-4.809, -1.589)


def _rel(a: float, b: float) -> float:
    return abs(a - b) / abs(b)


@pytest.mark.parametrize("name", ["sec4_2", "sec5_2"])
def test_fixed_point_follows_its_float64_twin(runs: dict, name: str) -> None:
    fx, fl, _ = runs[name]
    rms = math.sqrt(float(((fx.n_pct - fl.n_pct) ** 2).mean()))
    assert rms < 0.05  # %N
    keys = ("ap21", "ap22", "lam") + (("kx1", "kx2", "kr") if name == "sec5_2" else ())
    for k in keys:
        assert _rel(fx.estimates[k], fl.estimates[k]) < 0.01, k


def test_mrac_tracks_the_reference_model_and_meets_eq_5_14(runs: dict) -> None:
    fx, _, _ = runs["sec5_2"]
    last = fx.t >= fx.t[-1] - verify.TRACKING_WINDOW_S
    track = math.sqrt(float(((fx.n_pct[last] - fx.nref_pct[last]) ** 2).mean()))
    assert track < verify.TRACKING_TOL_PCT
    # the reference model itself reaches the command (unit DC gain, eq. 5.19)
    assert abs(fx.nref_pct[-1] - (89.68 - 1.0)) < 0.01
    # eq. 5.14: the gains satisfy the matching conditions with the current estimates
    e = fx.estimates
    assert abs(e["ap21"] + 25.0 + e["lam"] * e["kx1"]) < 0.05
    assert abs(e["ap22"] + 10.0 + e["lam"] * e["kx2"]) < 0.05
    assert abs(-25.0 + e["lam"] * e["kr"]) < 0.05


def test_rate_filter_effect_is_small_where_estimates_settle(runs: dict) -> None:
    """sec. 5.2 (closed loop): central difference on whole rpm vs the true rate."""
    _, fl, tr = runs["sec5_2"]
    for k in ("lam", "kx1", "kx2", "kr"):
        assert _rel(fl.estimates[k], tr.estimates[k]) < 0.01, k


@pytest.mark.xfail(
    strict=True,
    reason="the document's sec. 4.2 setup does not reach its published estimates in 300 s: an "
    "independent continuous-time integration of eq. 4.7/4.31 agrees with the twin (see "
    "test_continuous_time_reference_agrees_with_the_twin); Lambda-hat is near 1.0 at 300 s",
)
def test_sec_4_2_reaches_the_published_estimates(runs: dict) -> None:
    e = runs["sec4_2"][0].estimates
    a21, a22 = verify.PUBLISHED["ap_row2"]
    assert _rel(e["ap21"], a21) < 0.01
    assert _rel(e["ap22"], a22) < 0.01
    assert _rel(e["lam"], verify.PUBLISHED["lambda"]) < 0.01


@pytest.mark.xfail(
    strict=True,
    reason="with the document's sec. 5.2 gains Lambda-hat moves from 4.30 to about 4.30 in 300 s "
    "(Theta_f2 absorbs the pump gain: dN^2 is about 1 under a +-1 %N command)",
)
def test_sec_5_2_reaches_the_published_estimates(runs: dict) -> None:
    e = runs["sec5_2"][0].estimates
    assert _rel(e["lam"], verify.PUBLISHED["lambda"]) < 0.02
    kx1, kx2 = verify.PUBLISHED["kx_ideal"]
    assert _rel(e["kx1"], kx1) < 0.05 and _rel(e["kx2"], kx2) < 0.05
    assert _rel(abs(e["kr"]), verify.PUBLISHED["kr_ideal_abs"]) < 0.05


def _continuous_sec_4_2(seconds: float, dt: float) -> tuple[float, ...]:
    """Plant eq. 3.24 + identification model eq. 4.7 + laws eq. 4.31 as one ODE, RK4."""
    th = (-1.8054, -2.3360, 4.8220, -0.1835, -0.0001)
    am21, am22 = -0.36, -1.2
    ga, gl, gt1, gt2 = 20.0, 3.0, 0.01, 100.0

    def f(t: float, s: list[float]) -> list[float]:
        x1, x2, xh1, xh2, a21, a22, lam, t1, t2 = s
        u = 1.0 if (t % 20.0) < 10.0 else -1.0
        f1, f2 = x1 * u, x1 * x1 * u
        e2 = xh2 - x2
        return [
            x2,
            th[0] * x1 + th[1] * x2 + (th[2] + th[3] * x1 + th[4] * x1 * x1) * u,
            xh2,
            am21 * xh1 + am22 * xh2 + (a21 - am21) * x1 + (a22 - am22) * x2 + lam * u
            + t1 * f1 + t2 * f2,
            -ga * x1 * e2, -ga * x2 * e2, -gl * u * e2, -gt1 * f1 * e2, -gt2 * f2 * e2,
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


def test_continuous_time_reference_agrees_with_the_twin() -> None:
    """The discretised twin (true rate, as in the document) against the continuous equations."""
    p = verify.scenario_params("sec4_2")
    tw = verify.run_float(p, 30.0, true_rate=True).estimates
    a21, a22, lam, _, _ = _continuous_sec_4_2(30.0, 0.002)
    assert _rel(tw["lam"], lam) < 0.02
    assert abs(tw["ap21"] - a21) < 0.1 and abs(tw["ap22"] - a22) < 0.1
    assert lam < 1.2  # far from 4.822 after 30 s: slow convergence is in the equations


def test_sil_verify_json_rows(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["verify", "--json", "--seconds", "10"])
    rows = json.loads(capsys.readouterr().out)
    assert code in (0, 1)
    assert code == (0 if all(r["ok"] for r in rows) else 1)
    assert {"name", "published", "reached", "tolerance", "ok"} <= set(rows[0])
    names = [r["name"] for r in rows]
    assert "sec 4.2 Lambda" in names and "sec 5.2 |K_r|" in names
