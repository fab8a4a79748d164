"""The ECU core ported to C (``ecu_core.h``), bit-exact with the Python firmware: the build
(:mod:`ecu.port.build`) and the ctypes wrapper (:mod:`ecu.port.core`); its figures are
``sil bench port`` (:mod:`sil.bench.port`), its golden vectors come from :mod:`sil.run.golden`."""
