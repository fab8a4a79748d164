"""Compressor, turbine and gear-pump maps of the AMT Olympus-class engine, as data.

The document gives its maps only as figures (figs. 2.3-2.6, 2.9), so ``build.py`` here generates
smooth, physically shaped tables and calibrates them (and the nozzle area) so that the trim at
8 g/s is the published state of eq. 2.32. ``olympus_maps.npz`` holds the arrays,
``calibration.json`` what the calibration chose, ``*.png`` plots of the maps.
Regenerate with ``python -m plant.maps.build``.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from plant.compressor import CompressorMap
from plant.lookup import check_axis
from plant.pump import PumpTable
from plant.turbine import TurbineMap

MAPS_DIR = Path(__file__).resolve().parent
MAPS_FILE = MAPS_DIR / "olympus_maps.npz"
AXES = (
    "comp_beta",
    "comp_n_cor_pct",
    "comp_flow_axis",
    "turb_beta",
    "turb_n_t",
    "pump_voltage",
    "pump_pressure",
)


class EngineMaps(NamedTuple):
    compressor: CompressorMap
    turbine: TurbineMap
    pump: PumpTable
    nozzle_area_m2: float
    trim_pump_voltage: float  # pump voltage delivering the trim fuel flow at the trim P3


def load_maps(path: Path = MAPS_FILE) -> EngineMaps:
    """Read the tables written by build.py."""
    with np.load(path) as d:
        return maps_from_arrays({k: d[k] for k in d.files})


def maps_from_arrays(arrays: dict[str, np.ndarray]) -> EngineMaps:
    """The named arrays of olympus_maps.npz as the tables the model reads."""
    a = {k: np.ascontiguousarray(v, dtype=np.float64) for k, v in arrays.items()}
    for name in AXES:
        check_axis(name, a[name])
    return EngineMaps(
        compressor=CompressorMap(
            a["comp_beta"],
            a["comp_n_cor_pct"],
            a["comp_flow"],
            a["comp_flow_axis"],
            a["comp_efficiency"],
            a["comp_surge_beta"],
        ),
        turbine=TurbineMap(a["turb_beta"], a["turb_n_t"], a["turb_flow"], a["turb_efficiency"]),
        pump=PumpTable(
            a["pump_voltage"],
            a["pump_pressure"],
            a["pump_flow"],
            float(a["pump_current"][0]),
            float(a["pump_current"][1]),
            float(a["pump_current"][2]),
        ),
        nozzle_area_m2=float(a["nozzle_area_m2"][0]),
        trim_pump_voltage=float(a["trim_pump_voltage"][0]),
    )
