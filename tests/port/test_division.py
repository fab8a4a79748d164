"""The core's own 64-bit division (ecu_core.c div_trunc: 32-bit divisions only, for the
Cortex-M4) gives C's 64-bit division truncated toward zero, saturated to int32 with the
saturation counted, over the range the tick calls it with: dividends under 2^63, divisors under
2^32, both signs, the digit corrections' edge cases among them."""

import subprocess

from ecu.port import build

# div_trunc against the host's own 64-bit division; udiv64_32 (the inlet correction's quotient)
# against the host's unsigned one
HARNESS = r"""
#include "ecu_core.c"
#include <stdio.h>

static uint64_t state = 88172645463325252u;
static uint64_t next(void)
{
    state ^= state << 13;
    state ^= state >> 7;
    state ^= state << 17;
    return state;
}

static const uint64_t EDGES[] = {0u, 1u, 2u, 3u, 0xFFFFu, 0x10000u, 0x7FFFFFFFu, 0x80000000u,
                                 0x80000001u, 0xFFFF0000u, 0xFFFF8000u, 0xFFFFFFFFu};

/* a magnitude below 2^bits, or an edge, or a power of two and its neighbours */
static uint64_t magnitude(unsigned bits)
{
    uint64_t kind = next() % 8u;
    if (kind == 0u) {
        return EDGES[next() % 12u];
    }
    if (kind == 1u) {
        return ((uint64_t)1 << (next() % bits)) + next() % 3u - 1u;
    }
    return next() >> (64u - bits) >> (next() % bits);
}

int main(void)
{
    long bad = 0, n;
    for (n = 0; n < 2000000; n++) {
        ecu_t mine, ref;
        uint64_t ua = magnitude(63), ub = magnitude(32);
        int64_t a, b, q;
        int32_t want, got;
        ua = ua > (uint64_t)INT64_MAX ? (uint64_t)INT64_MAX : ua;
        ub = ub > 0xFFFFFFFFu ? 0xFFFFFFFFu : ub;
        if (next() % 4u == 0u && ub != 0u) { /* a high word just under the divisor's */
            ua = (ub - 1u - next() % 2u % ub) << 32 | (uint32_t)next();
            ua = ua > (uint64_t)INT64_MAX ? (uint64_t)INT64_MAX : ua;
        }
        a = next() & 1u ? -(int64_t)ua : (int64_t)ua;
        b = next() & 1u ? -(int64_t)ub : (int64_t)ub;
        mine.sat_pending = ref.sat_pending = 0;
        got = div_trunc(&mine, a, b);
        if (b == 0) {
            want = a > 0 ? INT32_MAX : (a < 0 ? INT32_MIN : 0);
            ref.sat_pending = 1;
        } else {
            q = a / b;
            want = q > INT32_MAX ? INT32_MAX : (q < INT32_MIN ? INT32_MIN : (int32_t)q);
            ref.sat_pending = want != q;
        }
        if (got != want || mine.sat_pending != ref.sat_pending ||
            (ub != 0u && udiv64_32(ua, (uint32_t)ub) != ua / ub)) {
            if (bad++ < 5) {
                printf("%lld / %lld: %ld, C gives %ld\n", (long long)a, (long long)b, (long)got,
                       (long)want);
            }
        }
    }
    printf("%ld of %ld differ\n", bad, n);
    return bad != 0;
}
"""


def test_division_equals_c_64_bit_division(tmp_path):
    source = tmp_path / "division.c"
    source.write_text(HARNESS)
    exe = tmp_path / "division"
    cc = build.host_compiler()
    subprocess.run(
        [cc, "-std=c99", "-O2", "-Wno-unused-function", f"-I{build.PORT_DIR}", str(source),
         "-o", str(exe)],
        check=True,
    )  # fmt: skip
    done = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stdout
    assert done.stdout.strip() == "0 of 2000000 differ"
