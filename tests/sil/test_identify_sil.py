"""Identification on recordings of our own SIL (aero-thermal plant, open loop on pump voltage).

Eq. 3.23 itself is not reachable term by term: our engine's speed response is first order with a
fast second pole (burner and plenums, about -56 rad/s) where the document's has two slow ones, so
omega_n and zeta differ (the plant issue reports it). What must agree is what the physics fixes:
the speed gain per volt alpha0 = theta2 / -theta0, and the fit quality.
"""

import subprocess
import sys

import numpy as np
import pytest

from sil.analysis import identify as ident

ALPHA0_EQ_3_23 = 2.6709


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("sil")
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "sil.cli",
                "run",
                name,
                "--mode",
                "inproc",
                "--out",
                str(out / name),
                "--no-plots",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        for name in ("thesis-3.3-staircase", "thesis-3.3-square", "thesis-3.3-sine")
    ]
    for p in procs:
        assert p.wait(timeout=600) == 0, p.stderr.read()
    return {
        name: ident.read_recording(out / name / "trace.csv", speed_column="speed_true")
        for name in ("thesis-3.3-staircase", "thesis-3.3-square", "thesis-3.3-sine")
    }


@pytest.mark.slow
def test_staircase_fit_predicts_the_square_and_sine_runs(runs):
    result = ident.identify(runs["thesis-3.3-staircase"])
    assert result.derived["alpha0"] == pytest.approx(ALPHA0_EQ_3_23, rel=0.30)
    assert result.derived["alpha1"] < 0  # gain falls with speed, as in eq. 3.23
    assert ident.validate(result, runs["thesis-3.3-square"]) < 5.0
    assert ident.validate(result, runs["thesis-3.3-sine"]) < 5.0


@pytest.mark.slow
def test_noisy_10_hz_version_of_the_staircase(runs):
    rec = runs["thesis-3.3-staircase"]
    rng = np.random.default_rng(1234)
    slow = ident.Recording(
        rec.t[::10],
        rec.n_pct[::10] + rng.normal(0, 0.05, len(rec.t[::10])),
        rec.v[::10],
        "10 Hz with noise",
    )
    result = ident.identify(slow)
    assert result.derived["alpha0"] == pytest.approx(ALPHA0_EQ_3_23, rel=0.40)
    # the steady gain survives; the dynamics do not: at 10 Hz, smoothing across our engine's
    # 0.6 s time constant leaves a slow, lightly damped fit (NRMSE about 20 % on the square run)
    assert all(complex(r).real < 0 for r in result.derived["roots"])
