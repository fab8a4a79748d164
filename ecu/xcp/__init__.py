"""Calibration and measurement with the field's own tools: the ECU's XCP slave on CAN
(:mod:`ecu.xcp.slave`), its memory map (:mod:`ecu.xcp.memory`), DAQ lists (:mod:`ecu.xcp.daq`),
seed and key (:mod:`ecu.xcp.seed_key`) and the A2L that describes them (:mod:`ecu.xcp.a2l`)."""
