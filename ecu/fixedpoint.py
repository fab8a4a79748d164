"""Fixed-point primitives: named Q formats on 32-bit signed values, 64-bit intermediates.

Conventions (CMSIS-DSP style, portable to C line by line):

- Every stored variable is a 32-bit signed integer whose format is in its name:
  ``_q24`` is Q7.24 (range +-128, resolution 2^-24 ~ 6e-8; engineering values in %N, %N/s, V,
  K and all adaptive parameters), ``_q16`` is Q15.16 (range +-32768; squared speed deviations
  and temperatures), ``_q28`` is Q3.28 (range +-8; learning gain times time step), ``_q40``
  is a 64-bit increment with 40 fractional bits fed to a split accumulator (below).
- Products are formed in 64 bits (``int64_t``) and truncated by arithmetic shift, which is
  what Python's ``>>`` on ints and ARM's ASR do (rounds toward minus infinity). The ``_round``
  variants add half an LSB first (round to nearest, ties up).
- Division truncates toward zero as C's ``/`` does (Python's ``//`` floors, so it has a helper).
  Division by zero is explicit: it returns the saturated value with the dividend's sign (0 for
  0/0) and counts a saturation event.
- Every store into a typed variable goes through :func:`sat32` (or a ``_sat`` primitive), which
  clamps instead of wrapping and counts the event in a sticky counter, like the ARM Q flag.
  Each firmware instance has its own counter (as the C port's ``ecu_t.sat_pending``): its tick
  makes it the one the primitives count into (:func:`counting_into`) and reads and clears it
  once per tick with :func:`take_sat_events`.
- Slow integrators (parameter update laws, where ``Gamma * x * e * dt`` is a few LSB of Q7.24)
  use a split accumulator: a Q7.24 word plus a 16-bit extension word, i.e. Q7.40 in two
  int32 words, so small increments are never lost to truncation (see :func:`acc_q40`).

No float appears here; conversion from engineering units lives in :mod:`ecu.firmware_params`.
"""

from __future__ import annotations

from array import array

INT32_MIN = -(1 << 31)
INT32_MAX = (1 << 31) - 1

Q24 = 24  # Q7.24
Q16 = 16  # Q15.16
Q28 = 28  # Q3.28
Q40 = 40  # Q7.40 (64-bit increments, split accumulators)
ONE_Q24 = 1 << Q24
ACC_EXT_BITS = Q40 - Q24  # bits held in the extension word of a split accumulator
ACC_EXT_MASK = (1 << ACC_EXT_BITS) - 1

# The sticky saturation counter the primitives count into (the ARM Q flag, counted): index 0
# holds the events since last read. A firmware instance puts its own in place for its tick.
_SAT_EVENTS = array("q", [0])


def new_sat_counter() -> array:
    """A saturation counter of one's own (an ECU instance's)."""
    return array("q", [0])


def counting_into(counter: array) -> array:
    """Make ``counter`` the one the primitives count into; returns the one it replaces."""
    global _SAT_EVENTS
    previous = _SAT_EVENTS
    _SAT_EVENTS = counter
    return previous


def take_sat_events(counter: array | None = None) -> int:
    """Return the saturation events counted in ``counter`` (default: the one in place) since
    the last call, and clear it."""
    c = _SAT_EVENTS if counter is None else counter
    n = c[0]
    c[0] = 0
    return n


def sat32(x: int) -> int:
    """Store a 64-bit intermediate into int32: clamp (never wrap) and count a clamp."""
    if INT32_MIN <= x <= INT32_MAX:
        return x
    if x > INT32_MAX:
        _SAT_EVENTS[0] += 1
        return INT32_MAX
    _SAT_EVENTS[0] += 1
    return INT32_MIN


def clamp(x: int, lo: int, hi: int) -> int:
    """Limit to [lo, hi]: a control limit, not an overflow, so it is not counted."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


def add_sat(a: int, b: int) -> int:
    """a + b, saturated to int32."""
    x = a + b
    return x if INT32_MIN <= x <= INT32_MAX else sat32(x)


def sub_sat(a: int, b: int) -> int:
    """a - b, saturated to int32."""
    x = a - b
    return x if INT32_MIN <= x <= INT32_MAX else sat32(x)


def mul_q(a: int, b: int, q: int) -> int:
    """(a * b) >> q: 64-bit product truncated by arithmetic shift, saturated to int32."""
    x = (a * b) >> q
    return x if INT32_MIN <= x <= INT32_MAX else sat32(x)


def mul_q_round(a: int, b: int, q: int) -> int:
    """(a * b + 2^(q-1)) >> q: 64-bit product rounded to nearest (ties up), saturated."""
    x = (a * b + (1 << (q - 1))) >> q
    return x if INT32_MIN <= x <= INT32_MAX else sat32(x)


def mul_q24(a: int, b: int) -> int:
    """Q7.24 x Q7.24 -> Q7.24, truncated."""
    x = (a * b) >> Q24
    return x if INT32_MIN <= x <= INT32_MAX else sat32(x)


def mul_q24_round(a: int, b: int) -> int:
    """Q7.24 x Q7.24 -> Q7.24, rounded to nearest."""
    x = (a * b + (1 << (Q24 - 1))) >> Q24
    return x if INT32_MIN <= x <= INT32_MAX else sat32(x)


def div_trunc(a: int, b: int) -> int:
    """a / b with C semantics (truncation toward zero), saturated; b == 0 saturates explicitly."""
    if b > 0:
        q = a // b if a >= 0 else -(-a // b)
    elif b < 0:
        q = -(a // -b) if a >= 0 else -a // -b
    else:
        _SAT_EVENTS[0] += 1
        if a > 0:
            return INT32_MAX
        if a < 0:
            return INT32_MIN
        return 0
    if INT32_MIN <= q <= INT32_MAX:
        return q
    return sat32(q)


def acc_q40(hi: array, lo: array, i: int, inc_q40: int) -> None:
    """Split accumulator: (hi[i], lo[i]) is a Q7.40 value in two int32 words; add a Q7.40 step.

    hi[i] is the Q7.24 value the firmware uses, lo[i] the 16 bits below it (0..65535). The sum is
    formed in 64 bits; on saturation the extension word is cleared.
    """
    total = (hi[i] << ACC_EXT_BITS) + lo[i] + inc_q40
    h = total >> ACC_EXT_BITS
    if INT32_MIN <= h <= INT32_MAX:
        hi[i] = h
        lo[i] = total & ACC_EXT_MASK
        return
    hi[i] = sat32(h)
    lo[i] = 0
