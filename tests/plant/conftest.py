"""Shared fixtures of the plant tests: the published numbers and the calibrated engine."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

REFERENCE = Path(__file__).resolve().parents[2] / ".." / "shared" / "reference"


@pytest.fixture(scope="session")
def reference() -> dict:
    return json.loads((REFERENCE / "thesis_reference.json").read_text())


@pytest.fixture(scope="session")
def model():
    from plant.aerothermal import make_model

    return make_model()


@pytest.fixture(scope="session")
def trim(model):
    from plant.trim import solve_steady

    return solve_steady(model, 0.008)


@pytest.fixture(scope="session")
def running(model) -> dict[str, np.ndarray]:
    from plant.steady_line import running_line

    return running_line(model)
