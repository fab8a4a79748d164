"""The ECU core ported to C (``ecu_core.h``), bit-exact with the Python firmware: the build
(:mod:`ecu.port.build`), the ctypes wrapper (:mod:`ecu.port.core`) and its figures
(:mod:`ecu.port.bench`)."""
