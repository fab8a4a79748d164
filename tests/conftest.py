"""Helpers every test folder may use, as fixtures."""

from collections.abc import Callable

import pytest


def _first_difference(a: bytes, b: bytes) -> str | None:
    """The first differing line of two logs, or None when they are equal (pytest's own diff of
    megabytes never ends)."""
    la, lb = a.splitlines(), b.splitlines()
    for i, (x, y) in enumerate(zip(la, lb, strict=False)):
        if x != y:
            return f"line {i + 1}: {x!r} != {y!r}"
    return None if len(la) == len(lb) else f"lengths differ: {len(la)} != {len(lb)} lines"


@pytest.fixture
def first_difference() -> Callable[[bytes, bytes], str | None]:
    return _first_difference
