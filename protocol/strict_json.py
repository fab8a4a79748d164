"""JSON as the project writes it: strict (RFC 8259), never the bare ``NaN`` or ``Infinity`` that
Python's :mod:`json` writes by default and strict readers (browsers, ``jq``, other languages)
refuse.

A number that is not finite (a figure with nothing to measure, a bound never reached) is written
as ``null``. NumPy scalars and arrays are written as numbers and lists. Every JSON file and every
``--json`` output of the project goes through :func:`dumps`.
"""

from __future__ import annotations

import json
import math
import numbers
from collections.abc import Callable
from typing import Any


def finite(value: Any) -> Any:
    """``value`` with every NaN or infinite number (at any depth) replaced by None, NumPy
    scalars and arrays by Python numbers and lists, tuples by lists."""
    if value is None or isinstance(value, bool | str):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        number = float(value)
        return number if math.isfinite(number) else None
    if isinstance(value, dict):
        return {key: finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [finite(item) for item in value]
    if hasattr(value, "tolist"):  # a NumPy array or scalar of another kind
        return finite(value.tolist())
    return value


def dumps(value: Any, *, default: Callable[[Any], Any] | None = None, **kwargs: Any) -> str:
    """:func:`json.dumps` of ``value`` with every non-finite number as null (see
    :func:`finite`); ``default`` converts other objects, and what it gives is made finite too."""
    fallback = None if default is None else (lambda obj: finite(default(obj)))
    return json.dumps(finite(value), allow_nan=False, default=fallback, **kwargs)


def loads(text: str) -> Any:
    """Parse JSON strictly: ``NaN``, ``Infinity`` and ``-Infinity`` are refused (ValueError)."""
    return json.loads(text, parse_constant=_refuse_constant)


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"not strict JSON: {name}")
