"""Small campaign files for the tests (short runs: the suite stays fast on two cores)."""

from pathlib import Path

import pytest

SMALL = """
name = "small"
base = "thesis-5.4-staircase"
duration_s = 3
seed = 4
samples = 2
nominal = true

[sample]
"plant.compressor_efficiency" = { uniform = [0.95, 1.05] }
"plant.pump_gain" = { uniform = [0.8, 1.2] }

[sweep]
"controller.kind" = ["mrac", "pid"]
"""

BUS = """
name = "bus"
base = "thesis-5.4-staircase"
duration_s = 2.5

[[variant]]
name = "flips"
[[variant.bus_fault]]
kind = "bitflip"
ids = ["PlantSensors"]
start_s = 1
duration_s = 0.5
rate = 0.5
detect = "E2E"

[[variant]]
name = "loss"
[[variant.bus_fault]]
kind = "drop"
ids = ["PlantSensors"]
start_s = 1
duration_s = 0.4
detect = "SENSOR_FRAME_LOST"
within_ticks = 5
fallback_mode = "FAULT"

[[variant]]
name = "short-loss"
[[variant.bus_fault]]
kind = "drop"
ids = ["PlantSensors"]
start_s = 1
duration_s = 0.05
detect = "SENSOR_FRAME_LOST"
within_ticks = 5
recover_within_ticks = 10
"""


@pytest.fixture
def write(tmp_path: Path):
    def _write(text: str, name: str = "campaign.toml") -> Path:
        path = tmp_path / name
        path.write_text(text)
        return path

    return _write


NOMINAL = """
name = "nominal"
base = "thesis-5.4-staircase"
duration_s = 3

[sweep]
"controller.kind" = ["mrac", "pid"]
"""
