"""Running a scenario: the runner (the node processes, in process or on a bus, in lockstep or in
real time), the command node, the compiled in-process loop, the recorder's process, the
liveness watches, the node processes' options, and the run's folder and record."""
