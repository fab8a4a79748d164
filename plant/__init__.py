"""The engine: aero-thermal model, gear pump, sensors, faults; the plant node.

Interface documented in README.md, section "Plant".
"""

from plant.jit import ensure_fresh

ensure_fresh()
