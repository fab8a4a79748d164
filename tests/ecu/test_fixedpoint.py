"""Fixed-point primitives against an exact rational oracle (fractions.Fraction + explicit clamp)."""

from __future__ import annotations

import math
from array import array
from fractions import Fraction

from hypothesis import example, given
from hypothesis import strategies as st

from ecu import fixedpoint as fp

I32 = st.integers(min_value=fp.INT32_MIN, max_value=fp.INT32_MAX)
LO, HI = fp.INT32_MIN, fp.INT32_MAX


def clamp_oracle(x: Fraction | int) -> tuple[int, bool]:
    """Exact value -> (int32 result, saturated?) for an already-integral value."""
    v = int(x)
    assert v == x
    if v > HI:
        return HI, True
    if v < LO:
        return LO, True
    return v, False


def events_of(fn, *args) -> tuple[int, int]:
    fp.take_sat_events()
    r = fn(*args)
    return r, fp.take_sat_events()


@given(I32, I32)
@example(LO, LO)
@example(LO, -1)
@example(HI, 1)
def test_add_sub_saturate_and_count(a: int, b: int) -> None:
    for fn, exact in ((fp.add_sat, a + b), (fp.sub_sat, a - b)):
        r, n = events_of(fn, a, b)
        want, sat = clamp_oracle(exact)
        assert r == want
        assert n == (1 if sat else 0)


@given(I32, I32, st.integers(min_value=1, max_value=31))
@example(LO, LO, 24)  # most negative times itself: +2^62 >> 24 does not fit
@example(LO, LO, 31)
@example(-1, 1, 24)  # truncation by arithmetic shift: -2^-24 -> -1 LSB, not 0
def test_mul_truncates_toward_minus_infinity(a: int, b: int, q: int) -> None:
    exact = math.floor(Fraction(a * b, 1 << q))
    r, n = events_of(fp.mul_q, a, b, q)
    want, sat = clamp_oracle(exact)
    assert r == want and n == (1 if sat else 0)
    if q == 24:
        assert fp.mul_q24(a, b) == want


@given(I32, I32, st.integers(min_value=1, max_value=31))
@example(LO, LO, 24)
@example(-3, 1 << 23, 24)  # -1.5 LSB rounds to -1 (ties up)
def test_mul_round_to_nearest_ties_up(a: int, b: int, q: int) -> None:
    exact = math.floor(Fraction(a * b, 1 << q) + Fraction(1, 2))
    want, _ = clamp_oracle(exact)
    assert fp.mul_q_round(a, b, q) == want
    if q == 24:
        assert fp.mul_q24_round(a, b) == want


def test_mul_q24_examples() -> None:
    half = 1 << 23
    assert fp.mul_q24(half, half) == 1 << 22  # 0.5 * 0.5 = 0.25
    assert fp.mul_q24(-half, half) == -(1 << 22)
    assert fp.mul_q24(fp.ONE_Q24, 3) == 3


@given(I32, I32)
@example(LO, -1)  # the one int32 quotient that overflows
@example(-7, 2)  # C: -3 (Python // gives -4)
@example(7, -2)
@example(5, 0)
@example(-5, 0)
@example(0, 0)
def test_div_trunc_has_c_semantics(a: int, b: int) -> None:
    r, n = events_of(fp.div_trunc, a, b)
    if b == 0:
        assert n == 1
        assert r == (HI if a > 0 else LO if a < 0 else 0)
        return
    exact = math.trunc(Fraction(a, b))  # toward zero
    want, sat = clamp_oracle(exact)
    assert r == want and n == (1 if sat else 0)


@given(
    st.integers(min_value=-(1 << 30), max_value=1 << 30),
    st.integers(min_value=0, max_value=(1 << 16) - 1),
    st.lists(st.integers(min_value=-(1 << 45), max_value=1 << 45), max_size=30),
)
def test_split_accumulator_is_exact_q40(hi0: int, lo0: int, incs: list[int]) -> None:
    hi = array("i", [hi0])
    lo = array("i", [lo0])
    exact = Fraction(hi0 * (1 << 16) + lo0, 1 << 40)
    for inc in incs:
        fp.acc_q40(hi, lo, 0, inc)
        exact += Fraction(inc, 1 << 40)
        total = exact * (1 << 40)
        if total >= (HI + 1) << 16 or total < LO << 16:  # the oracle saturates too
            want_hi, _ = clamp_oracle(HI if total > 0 else LO)
            assert (hi[0], lo[0]) == (want_hi, 0)
            exact = Fraction(hi[0] * (1 << 16), 1 << 40)
            continue
        assert Fraction(hi[0] * (1 << 16) + lo[0], 1 << 40) == exact
        assert 0 <= lo[0] < 1 << 16


def test_split_accumulator_keeps_sub_lsb_steps() -> None:
    """A step of a quarter LSB of Q7.24 adds up exactly (a plain Q7.24 store would drop it)."""
    hi = array("i", [0])
    lo = array("i", [0])
    for _ in range(4000):
        fp.acc_q40(hi, lo, 0, 1 << 14)
    assert (hi[0], lo[0]) == (1000, 0)


def test_sat_events_count_and_clear() -> None:
    fp.take_sat_events()
    fp.sat32(HI + 5)
    fp.sat32(LO - 5)
    fp.sat32(0)
    assert fp.take_sat_events() == 2
    assert fp.take_sat_events() == 0


def test_clamp_is_not_an_overflow() -> None:
    fp.take_sat_events()
    assert fp.clamp(5, 0, 3) == 3 and fp.clamp(-5, 0, 3) == 0 and fp.clamp(2, 0, 3) == 2
    assert fp.take_sat_events() == 0
