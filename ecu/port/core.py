"""The C core through ctypes, with the Python firmware's interface (``Ecu``): ``p``, ``s``,
``out``, ``reset()`` and ``tick(inputs) -> outputs``, so the CAN node runs either.

The records' layouts are not restated here: they are read from the library's field-name strings
(the X-macro lists of ``ecu_core.h``) and checked against the Python firmware's ``FIELDS``,
so a field added on one side only is refused at load time with its name.
"""

from __future__ import annotations

import ctypes
import operator
import re
import struct
from functools import cache

from ecu.firmware import EcuInputs, EcuOutputs
from ecu.firmware_params import FirmwareParams, compile_params
from ecu.params import EcuParams
from ecu.port.build import host_library
from ecu.state import EcuState

_FIELD = re.compile(r"(\w+)(?:\[(\d+)\])?")


class PortError(RuntimeError):
    """The C core and the Python firmware disagree on a record, or a parameter is refused."""


def _record(lib: ctypes.CDLL, symbol: str, expected: tuple[str, ...], what: str) -> type:
    start = ctypes.addressof(ctypes.c_char.in_dll(lib, symbol))
    text = ctypes.cast(start, ctypes.c_char_p).value.decode()
    fields: list[tuple[str, type]] = []
    for name, count in _FIELD.findall(text):
        fields.append((name, ctypes.c_int32 * int(count) if count else ctypes.c_int32))
    names = tuple(name for name, _ in fields)
    if names != expected:
        diff = next(
            (
                f"{a!r} (C) vs {b!r} (Python)"
                for a, b in zip(names, expected, strict=False)
                if a != b
            ),
            f"{len(names)} fields (C) vs {len(expected)} (Python)",
        )
        raise PortError(f"ecu_core.h {what} differs from the Python firmware: {diff}")
    return type(what, (ctypes.Structure,), {"_fields_": fields})


class _Lib:
    def __init__(self) -> None:
        lib = ctypes.CDLL(str(host_library()))
        self.params_t = _record(lib, "ecu_param_names", FirmwareParams.FIELDS, "ecu_params_t")
        self.state_t = _record(lib, "ecu_state_names", EcuState.FIELDS, "ecu_state_t")
        self.inputs_t = _record(lib, "ecu_input_names", EcuInputs.FIELDS, "ecu_inputs_t")
        self.outputs_t = _record(lib, "ecu_output_names", EcuOutputs.FIELDS, "ecu_outputs_t")
        self.ecu_t = type(
            "ecu_t",
            (ctypes.Structure,),
            {
                "_fields_": [
                    ("p", ctypes.POINTER(self.params_t)),
                    ("s", self.state_t),
                    ("o", self.outputs_t),
                    ("sat_pending", ctypes.c_int32),
                    ("rate_q24", ctypes.c_int32),
                ]
            },
        )
        lib.ecu_params_load.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t]
        lib.ecu_params_load.restype = ctypes.c_int
        lib.ecu_init.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
        lib.ecu_init.restype = None
        lib.ecu_tick.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
        lib.ecu_tick.restype = ctypes.c_void_p
        lib.ecu_state_digest.argtypes = [ctypes.c_void_p]
        lib.ecu_state_digest.restype = ctypes.c_uint32
        self.lib = lib


@cache
def library() -> _Lib:
    """The host build, compiled on first use (see :mod:`ecu.port.build`)."""
    return _Lib()


def param_words(p: FirmwareParams) -> list[int]:
    """The parameter words in ``ecu_params_t`` order (the tuple init_theta_q24 expanded)."""
    words: list[int] = []
    for name in FirmwareParams.FIELDS:
        value = getattr(p, name)
        for v in value if isinstance(value, tuple) else (value,):
            if not -(1 << 31) <= v < (1 << 31):
                raise PortError(f"FirmwareParams.{name} = {v} does not fit an int32 word")
            words.append(v)
    return words


def _param_name(index: int) -> str:
    names = [
        name for name, t in library().params_t._fields_ for _ in range(getattr(t, "_length_", 1))
    ]
    return names[index] if index < len(names) else "(word count)"


class CEcu:
    """The C firmware behind the Python firmware's interface (see the module docstring).

    Assigning ``p`` (a new FirmwareParams) loads it into the C parameter record the instance
    runs on, from the next tick, as assigning ``Ecu.p`` does (the service port's parameter
    writes); a refused set leaves the running one untouched.
    """

    def __init__(self, params: EcuParams | FirmwareParams | None = None) -> None:
        if params is None:
            params = EcuParams()
        lib = library()
        self._params = lib.params_t()
        self.p = params if isinstance(params, FirmwareParams) else compile_params(params)
        self._ecu = lib.ecu_t()
        self._in = lib.inputs_t()
        self._tick = lib.lib.ecu_tick
        self._refs = (ctypes.byref(self._ecu), ctypes.byref(self._in))
        # the inputs in one C-level step: read in the record's field order, stored as int32
        self._read_inputs = operator.attrgetter(*(name for name, _ in lib.inputs_t._fields_))
        self._store_inputs = struct.Struct(f"={len(lib.inputs_t._fields_)}i").pack_into
        self.s = self._ecu.s
        self.out = self._ecu.o
        self.reset()

    @property
    def p(self) -> FirmwareParams:
        return self._p

    @p.setter
    def p(self, params: FirmwareParams) -> None:
        lib = library()
        words = param_words(params)
        loaded = lib.params_t()
        c_words = (ctypes.c_int32 * len(words))(*words)
        bad = lib.lib.ecu_params_load(ctypes.byref(loaded), c_words, len(words))
        if bad >= 0:
            raise PortError(f"ecu_params_load refused FirmwareParams.{_param_name(bad)}")
        ctypes.pointer(self._params)[0] = loaded  # in place: ecu_t points at this record
        self._p = params

    def reset(self) -> None:
        """Power-on initialisation (``ecu_init``)."""
        library().lib.ecu_init(ctypes.byref(self._ecu), ctypes.byref(self._params))

    def tick(self, i: EcuInputs):  # noqa: ANN201 (an outputs_t with EcuOutputs' fields)
        self._store_inputs(self._in, 0, *self._read_inputs(i))  # (struct.error beyond int32)
        self._tick(*self._refs)
        return self.out

    def digest(self) -> int:
        """FNV-1a of the state words, as the C core computes it (``ecu_state_digest``)."""
        return library().lib.ecu_state_digest(ctypes.byref(self.s))


IMPLEMENTATIONS = ("python", "c")


def make_ecu(impl: str, params: EcuParams | FirmwareParams | None = None):  # noqa: ANN201
    """The firmware by implementation name: ``python`` (ecu.firmware.Ecu) or ``c`` (CEcu)."""
    if impl == "python":
        from ecu.firmware import Ecu

        return Ecu(params)
    if impl == "c":
        return CEcu(params)
    raise ValueError(f"ECU implementation {impl!r}: expected one of {', '.join(IMPLEMENTATIONS)}")
