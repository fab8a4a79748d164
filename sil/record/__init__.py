"""What a run leaves and what reads it back: the recorder (ticks, frame checks, trace.csv), the
CAN log formats (candump, ASC, BLF, TRC, CSV, MF4), the run's files, replay, and XCP DAQ
recordings."""
