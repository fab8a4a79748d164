"""Plant status flags: one bit each, set by the model and reported with every output."""

from __future__ import annotations

from enum import IntFlag

# Plain ints so numba-compiled code can use them as constants.
COMPRESSOR_MAP_CLAMPED = 1 << 0
TURBINE_MAP_CLAMPED = 1 << 1
PUMP_MAP_CLAMPED = 1 << 2
SURGE = 1 << 3
FLAMEOUT = 1 << 4
OVERSPEED = 1 << 5
OVERTEMPERATURE = 1 << 6
NOZZLE_CHOKED = 1 << 7
PUMP_UNPOWERED = 1 << 8
LEAN_LIMIT = 1 << 9


class PlantFlag(IntFlag):
    """Decoded view of the flag word (``PlantFlag(outputs.flags)``)."""

    COMPRESSOR_MAP_CLAMPED = COMPRESSOR_MAP_CLAMPED
    TURBINE_MAP_CLAMPED = TURBINE_MAP_CLAMPED
    PUMP_MAP_CLAMPED = PUMP_MAP_CLAMPED
    SURGE = SURGE
    FLAMEOUT = FLAMEOUT
    OVERSPEED = OVERSPEED
    OVERTEMPERATURE = OVERTEMPERATURE
    NOZZLE_CHOKED = NOZZLE_CHOKED
    PUMP_UNPOWERED = PUMP_UNPOWERED
    LEAN_LIMIT = LEAN_LIMIT
