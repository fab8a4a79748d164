"""The engine: aero-thermal turbojet model, gear pump, sensors, faults; the plant node."""
