"""The engine: aero-thermal model, gear pump, sensors, faults; the plant node.

Interface documented in docs/plant.md.
"""

from plant.jit import ensure_fresh

ensure_fresh()
