"""The ECU service port: a framed binary protocol over a serial line (UART, pseudo-terminal or a
pyserial URL) for a ground-support unit or a laptop.

Layers, bottom up, one module each:

- :mod:`ecu.service.crc` and :mod:`ecu.service.framing`: COBS frames, each a payload and its
  CRC-16/CCITT-FALSE, delimited by zero bytes; a decoder that drops and counts malformed,
  oversized and CRC-failing frames and resynchronises on the next delimiter;
- :mod:`ecu.service.message`: the message header (protocol version, kind, sequence number,
  service, status) and a msgpack body;
- :mod:`ecu.service.param_table`: the named parameters a service tool may read and write, with
  their Q format, units, limits and whether they may change while the engine runs;
- :mod:`ecu.service.storage`: the emulated two-slot flash image that keeps the parameter set;
- :mod:`ecu.service.fault_log` and :mod:`ecu.service.live`: the fault log and the live-data record;
- :mod:`ecu.service.transport`: non-blocking byte I/O on a serial port, a pty or a pyserial URL;
- :mod:`ecu.service.port`: the ECU side, serviced once per tick within a fixed budget.
"""
