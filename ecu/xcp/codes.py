"""The numbers of ASAM MCD-1 XCP 1.x that the slave speaks: packet identifiers, command codes,
error codes, event codes, resource bits and the bits of the mode and property bytes."""

from __future__ import annotations

from enum import IntEnum

# packet identifiers of the slave's packets (0x00..0xFB: DAQ, the absolute ODT number)
PID_RES = 0xFF
PID_ERR = 0xFE
PID_EV = 0xFD
PID_SERV = 0xFC
PID_DAQ_MAX = 0xFB


class Cmd(IntEnum):
    CONNECT = 0xFF
    DISCONNECT = 0xFE
    GET_STATUS = 0xFD
    SYNCH = 0xFC
    GET_COMM_MODE_INFO = 0xFB
    GET_ID = 0xFA
    SET_REQUEST = 0xF9
    GET_SEED = 0xF8
    UNLOCK = 0xF7
    SET_MTA = 0xF6
    UPLOAD = 0xF5
    SHORT_UPLOAD = 0xF4
    BUILD_CHECKSUM = 0xF3
    TRANSPORT_LAYER_CMD = 0xF2
    USER_CMD = 0xF1
    DOWNLOAD = 0xF0
    DOWNLOAD_NEXT = 0xEF
    DOWNLOAD_MAX = 0xEE
    SHORT_DOWNLOAD = 0xED
    MODIFY_BITS = 0xEC
    CLEAR_DAQ_LIST = 0xE3
    SET_DAQ_PTR = 0xE2
    WRITE_DAQ = 0xE1
    SET_DAQ_LIST_MODE = 0xE0
    GET_DAQ_LIST_MODE = 0xDF
    START_STOP_DAQ_LIST = 0xDE
    START_STOP_SYNCH = 0xDD
    GET_DAQ_CLOCK = 0xDC
    READ_DAQ = 0xDB
    GET_DAQ_PROCESSOR_INFO = 0xDA
    GET_DAQ_RESOLUTION_INFO = 0xD9
    GET_DAQ_LIST_INFO = 0xD8
    GET_DAQ_EVENT_INFO = 0xD7
    FREE_DAQ = 0xD6
    ALLOC_DAQ = 0xD5
    ALLOC_ODT = 0xD4
    ALLOC_ODT_ENTRY = 0xD3


class Err(IntEnum):
    CMD_SYNCH = 0x00  # the answer to SYNCH
    CMD_BUSY = 0x10
    DAQ_ACTIVE = 0x11
    PGM_ACTIVE = 0x12
    CMD_UNKNOWN = 0x20
    CMD_SYNTAX = 0x21
    OUT_OF_RANGE = 0x22
    WRITE_PROTECTED = 0x23
    ACCESS_DENIED = 0x24
    ACCESS_LOCKED = 0x25
    PAGE_NOT_VALID = 0x26
    MODE_NOT_VALID = 0x27
    SEGMENT_NOT_VALID = 0x28
    SEQUENCE = 0x29
    DAQ_CONFIG = 0x2A
    MEMORY_OVERFLOW = 0x30
    GENERIC = 0x31
    VERIFY = 0x32
    RESOURCE_TEMPORARY_NOT_ACCESSIBLE = 0x33


class Ev(IntEnum):
    RESUME_MODE = 0x00
    CLEAR_DAQ = 0x01
    STORE_DAQ = 0x02
    STORE_CAL = 0x03
    CMD_PENDING = 0x05
    DAQ_OVERLOAD = 0x06
    SESSION_TERMINATED = 0x07


# resources (CONNECT's RESOURCE byte, GET_STATUS's protection byte, GET_SEED's resource)
RES_CAL_PAG = 0x01
RES_DAQ = 0x04
RES_STIM = 0x08
RES_PGM = 0x10

# COMM_MODE_BASIC: Intel byte order (bit 0 clear), byte granularity (bits 1-2 clear)
COMM_MODE_BASIC_OPTIONAL = 0x80  # GET_COMM_MODE_INFO gives more
COMM_MODE_BASIC_SLAVE_BLOCK = 0x40
COMM_MODE_OPTIONAL_MASTER_BLOCK = 0x01

# GET_STATUS's SESSION_STATUS
SESSION_STORE_CAL_REQ = 0x01
SESSION_DAQ_RUNNING = 0x40

# SET_REQUEST's mode
REQUEST_STORE_CAL = 0x01
REQUEST_STORE_DAQ_NO_RESUME = 0x02
REQUEST_STORE_DAQ_RESUME = 0x04
REQUEST_CLEAR_DAQ = 0x08

# GET_ID types (1 and 2: the A2L's name without and with its extension)
ID_ASCII = 0
ID_A2L_NAME = 1
ID_A2L_FILE = 2

# SET_DAQ_LIST_MODE's mode and GET_DAQ_LIST_MODE's current mode
DAQ_MODE_ALTERNATING = 0x01
DAQ_MODE_DIRECTION_STIM = 0x02
DAQ_MODE_DTO_CTR = 0x08
DAQ_MODE_TIMESTAMP = 0x10
DAQ_MODE_PID_OFF = 0x20
DAQ_MODE_SELECTED = 0x01  # current mode
DAQ_MODE_RUNNING = 0x40  # current mode

# GET_DAQ_PROCESSOR_INFO's DAQ_PROPERTIES: dynamic, prescaler, timestamps
DAQ_PROPERTY_DYNAMIC = 0x01
DAQ_PROPERTY_PRESCALER = 0x02
DAQ_PROPERTY_TIMESTAMP = 0x10
# GET_DAQ_EVENT_INFO's properties: DAQ lists only, consistency per event channel
EVENT_PROPERTY_DAQ = 0x04
EVENT_CONSISTENCY_EVENT = 0x80
# time units (GET_DAQ_EVENT_INFO, and the TIMESTAMP_MODE's high nibble)
UNIT_1US = 3
UNIT_1MS = 6
# TIMESTAMP_MODE: size DWORD (4), fixed (always sent), unit 1 us
TIMESTAMP_SIZE = 4
TIMESTAMP_MODE = (UNIT_1US << 4) | 0x08 | 0x04

CHECKSUM_CRC_16_CITT = 0x08
