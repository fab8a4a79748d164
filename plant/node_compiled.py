"""The plant node's compiled twin, for a lockstep run in one compiled loop
(sil/run/compiled_loop.py).

PlantNode's lockstep handling of EcuActuator and its advance, operation for operation, on an
int64 state array (the NS_ slots) and a float64 one (NF_): the Python parts of a period (faults
falling due, noise blocks) stay in Python (PlantNode.python_part), which the caller runs when
``python_due`` says so, as do the EcuStarter and FaultInject frames (PlantNode.on_frame).
PlantNode.to_compiled() and from_compiled() move the node's and its plant's state in and out.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from plant.aerothermal import aero_period
from plant.fast_plant import fast_period
from plant.frames import CRC_TABLE, DUE_ANALOG, DUE_TRUTH, pack_plant_frames
from plant.jit import EXACT
from plant.periphery import IGNITER, STARTER_DUTY
from protocol.e2e import COUNTER_MODULO, E2EStatus
from protocol.lockstep import TICK_MODULO

(
    NS_TICK,  # PlantNode.tick
    NS_PLANT_TICK,  # the plant's ticks stepped (PlantBase._tick)
    NS_NOISE_LEFT,  # samples left in the noise blocks (PlantBase._noise_left)
    NS_FAULT_TICK,  # the earliest tick of the faults the node holds (pending), else NO_TICK
    NS_FLAGS,  # the plant's flags after its last period (plant.outputs.flags)
    NS_FRESH,
    NS_MISSED,
    NS_WATCHDOG,  # watchdog_ticks
    NS_TRIPS,  # watchdog_trips
    NS_PUMP_ENABLED,
    NS_REJECTED,  # actuator_rejected
    NS_LATE,  # actuator_late
    NS_AHEAD,  # actuator_ahead
    NS_MAX_TICKS,  # max_ticks, or -1
    NS_FINISHED,
    NS_EVERY_TRUTH,
    NS_EVERY_ANALOG,
    NS_KERNEL,  # index of the plant's kernel in KERNELS
    NS_CHECK_LAST,  # the actuator checker's last accepted counter (-1: none)
    NS_CHECK_STATUS,  # its last status
    NS_CHECK_CRC,  # its CRC register after the data ID
    NS_STARTER_MISSED,  # ticks since the last valid EcuStarter frame (PlantNode.starter_missed)
) = range(22)
NS_CHECK_COUNTS = 22  # its counts per E2EStatus
NS_FIELDS = NS_CHECK_COUNTS + len(E2EStatus)  # (start, mask, sign bit) per EcuActuator field
NS_SIZE = NS_FIELDS + 3 * 5
NF_DUTY, NF_FAULT_NEXT_S, NF_PERIOD, NF_SIZE = 0, 1, 2, 3
NO_TICK = 1 << 62
KERNELS = (aero_period, fast_period)  # the plants' compiled periods, by NS_KERNEL
_OK, _WRONGCRC, _REPEATED, _WRONGSEQUENCE = (
    int(E2EStatus.OK),
    int(E2EStatus.WRONGCRC),
    int(E2EStatus.REPEATED),
    int(E2EStatus.WRONGSEQUENCE),
)
_ACTUATOR_MAX_DELTA = 2  # PlantNode.actuator_check


@njit(**EXACT, inline="always")
def _actuator_check(ns: np.ndarray, lay: np.ndarray, data: np.ndarray) -> int:
    """E2EChecker.check of the node's actuator checker."""
    crc = ns[NS_CHECK_CRC]
    for i in range(1, 8):
        crc = lay[CRC_TABLE + (crc ^ data[i])]
    counter = data[1] & 0x0F
    if counter >= COUNTER_MODULO or crc != data[0]:
        status = _WRONGCRC
    else:
        last = ns[NS_CHECK_LAST]
        if last < 0:
            status = _OK
        else:
            delta = (counter - last) % COUNTER_MODULO
            if delta == 0:
                status = _REPEATED
            elif delta <= _ACTUATOR_MAX_DELTA:
                status = _OK
            else:
                status = _WRONGSEQUENCE
        if status != _REPEATED:
            ns[NS_CHECK_LAST] = counter
    ns[NS_CHECK_STATUS] = status
    ns[NS_CHECK_COUNTS + status] += 1
    return status


@njit(**EXACT, inline="always")
def _raw(ns: np.ndarray, word: int, i: int) -> int:
    """Field i of EcuActuator from the frame's 64-bit word (MessageCodec.unpack_raw)."""
    f = NS_FIELDS + 3 * i
    raw = (word >> ns[f]) & ns[f + 1]
    sign = ns[f + 2]
    return raw - (sign << 1) if sign and raw & sign else raw


@njit(**EXACT)
def actuator_compiled(ns: np.ndarray, nf: np.ndarray, lay: np.ndarray, data: np.ndarray) -> bool:
    """PlantNode._on_actuator in lockstep, to the advance: True when ``data`` (uint8[8]) answers
    this tick (the command taken and the watchdog counted, as _advance begins); the period
    itself is advance_compiled, after PlantNode.python_part when python_due."""
    if _actuator_check(ns, lay, data) != _OK:
        ns[NS_REJECTED] += 1
        return False
    word = 0
    for i in range(8):
        word |= np.int64(data[i]) << (8 * i)
    behind = (ns[NS_TICK] - _raw(ns, word, 2)) % TICK_MODULO
    if behind != 0:
        if behind < TICK_MODULO // 2:
            ns[NS_LATE] += 1
        else:
            ns[NS_AHEAD] += 1
        return False
    ns[NS_PUMP_ENABLED] = 1 if _raw(ns, word, 0) != 0 else 0  # _command
    duty = _raw(ns, word, 3)
    nf[NF_DUTY] = (0 if duty < 0 else 10000 if duty > 10000 else duty) * 1e-4
    ns[NS_MISSED] = 0  # _advance with a fresh command
    ns[NS_FRESH] = 0
    return True


@njit(**EXACT)
def python_due(ns: np.ndarray, nf: np.ndarray) -> bool:
    """Before the period: PlantNode.python_part has something to do (a fault the node holds
    falls due, the plant's fault schedule, the noise blocks run out)."""
    return (
        ns[NS_FAULT_TICK] <= ns[NS_TICK]
        or nf[NF_FAULT_NEXT_S] <= ns[NS_PLANT_TICK] * nf[NF_PERIOD] + 1e-9
        or ns[NS_NOISE_LEFT] == 0
    )


@njit(**EXACT)
def advance_compiled(
    s: np.ndarray, tables: np.ndarray, ns: np.ndarray, nf: np.ndarray, lay: np.ndarray,
    buf: np.ndarray,
) -> int:  # fmt: skip
    """The rest of PlantNode._advance: the plant's period (PlantBase._period_with) and the next
    tick's frames packed into buf (FRAMES order); returns which are due (DUE_ bits)."""
    powered = ns[NS_PUMP_ENABLED] != 0 and ns[NS_MISSED] <= ns[NS_WATCHDOG]
    u = nf[NF_DUTY] if powered else 0.0
    if ns[NS_STARTER_MISSED] >= ns[NS_WATCHDOG]:  # no EcuStarter for the watchdog's time
        s[STARTER_DUTY] = 0.0
        s[IGNITER] = 0.0
    tick = ns[NS_PLANT_TICK] + 1
    if ns[NS_KERNEL] == 0:
        flags = aero_period(s, tables, u, powered, tick, True)
    else:
        flags = fast_period(s, tables, u, powered, tick, True)
    ns[NS_STARTER_MISSED] += 1
    ns[NS_NOISE_LEFT] -= 1
    ns[NS_PLANT_TICK] = tick
    ns[NS_FLAGS] = flags
    k = ns[NS_TICK] + 1
    ns[NS_TICK] = k
    if ns[NS_MAX_TICKS] >= 0 and k >= ns[NS_MAX_TICKS]:
        ns[NS_FINISHED] = 1
    due = (DUE_TRUTH if k % ns[NS_EVERY_TRUTH] == 0 else 0) | (
        DUE_ANALOG if k % ns[NS_EVERY_ANALOG] == 0 else 0
    )
    pack_plant_frames(s, lay, buf, flags, k % TICK_MODULO, due)
    return due
