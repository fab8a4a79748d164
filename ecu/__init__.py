"""ECU firmware: fixed-point control loop, estimator, MRAC, PID, protection, modes."""

from ecu.compiled_tick import activate

COMPILED = activate(__path__)  # the tick's compiled modules, when built from these sources
