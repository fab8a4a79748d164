"""Strict JSON: no bare NaN or Infinity in anything the project writes."""

import math

import numpy as np
import pytest

from protocol import strict_json


def test_non_finite_numbers_become_null_at_any_depth():
    value = {
        "nan": math.nan,
        "inf": [1.0, math.inf, (-math.inf, 2)],
        "numpy": {"f32": np.float32("nan"), "f64": np.float64(2.5), "i": np.int64(3)},
        "array": np.array([1.0, np.nan]),
        "flag": True,
        "none": None,
    }
    text = strict_json.dumps(value)
    assert strict_json.loads(text) == {
        "nan": None,
        "inf": [1.0, None, [None, 2]],
        "numpy": {"f32": None, "f64": 2.5, "i": 3},
        "array": [1.0, None],
        "flag": True,
        "none": None,
    }


def test_default_conversions_are_made_finite_too():
    assert strict_json.dumps({"x": object()}, default=lambda _: math.inf) == '{"x": null}'


@pytest.mark.parametrize("constant", ["NaN", "Infinity", "-Infinity"])
def test_the_strict_reader_refuses_bare_constants(constant):
    with pytest.raises(ValueError, match=constant):
        strict_json.loads(f'{{"a": {constant}}}')
