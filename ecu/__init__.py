"""ECU firmware: fixed-point control loop, estimator, MRAC, PID, protection, modes."""
