"""The bus fault injector: each kind against independent expectations, and its determinism."""

import math

import pytest
from e2e.p01 import e2e_p01_check

from protocol.codec import Codec
from protocol.e2e import E2EChecker, E2EStatus
from sil.busfault.injector import Injector
from sil.busfault.spec import BusFault

RATE = 100.0
CODEC = Codec()
SENSORS = CODEC["PlantSensors"]


def frames(n: int):
    """n PlantSensors frames as the plant sends them, one per tick, with their counters."""
    for tick in range(n):
        SENSORS.pack_raw([tick % 65536, 90_000 + tick % 1000, 10_480])
        yield tick, bytes(SENSORS.data)


def run(fault: BusFault, n: int = 1000, seed: int = 1):
    injector = Injector((fault,), RATE, seed, CODEC)
    out = [(tick, injector.transmit(tick, SENSORS.frame_id, data)) for tick, data in frames(n)]
    return injector, out


@pytest.mark.parametrize("bits", [1, 2])
def test_bit_flips_are_rejected_by_our_checker_and_by_autosar_e2e(bits):
    fault = BusFault("bitflip", (SENSORS.frame_id,), 0.0, 100.0, rate=1.0, bits=bits)
    injector, out = run(fault, 3000)
    assert len(injector.events) == 3000
    originals = dict(frames(3000))
    for tick, (c,) in out:
        diff = sum(bin(a ^ b).count("1") for a, b in zip(c.data, originals[tick], strict=True))
        assert diff == bits and c.data[0] == originals[tick][0]  # payload bits, not the CRC
        assert E2EChecker(SENSORS.data_id).check(c.data) == E2EStatus.WRONGCRC
        assert not e2e_p01_check(bytearray(c.data), SENSORS.data_id)


def test_three_bit_flips_escape_crc8_as_often_as_its_distance_says():
    """CRC-8 0x1D over our 9 bytes has Hamming distance 3: every 1- and 2-bit error is caught,
    141 of the 27,720 3-bit patterns in bytes 1..7 are not (counted exhaustively, the CRC is
    linear so this holds for any payload); both checkers agree frame by frame."""
    fault = BusFault("bitflip", (SENSORS.frame_id,), 0.0, 1000.0, rate=1.0, bits=3)
    _, out = run(fault, 20_000)
    passed = 0
    for _, (c,) in out:
        ours = E2EChecker(SENSORS.data_id).check(c.data) != E2EStatus.WRONGCRC
        assert ours == e2e_p01_check(bytearray(c.data), SENSORS.data_id)
        passed += ours
    p = 141 / 27_720
    assert abs(passed - 20_000 * p) < 4.5 * math.sqrt(20_000 * p)


@pytest.mark.parametrize("rate", [0.05, 0.3])
def test_drop_rate_within_binomial_bounds(rate):
    n = 20_000
    fault = BusFault("drop", (SENSORS.frame_id,), 0.0, n / RATE, rate=rate)
    injector, out = run(fault, n)
    dropped = sum(1 for _, copies in out if not copies)
    sigma = math.sqrt(n * rate * (1 - rate))
    assert abs(dropped - n * rate) < 4.5 * sigma
    assert dropped == len(injector.events)


def test_drop_bursts_lose_that_many_frames_in_a_row():
    fault = BusFault("drop", (SENSORS.frame_id,), 0.0, 100.0, rate=0.02, burst=7)
    _, out = run(fault, 10_000)
    runs, length = [], 0
    for _, copies in out:
        if copies:
            if length:
                runs.append(length)
            length = 0
        else:
            length += 1
    assert runs and all(r % 7 == 0 for r in runs)
    # a loss starts with probability 0.02 per frame not already in a burst
    starts = sum(r // 7 for r in runs)
    expected = 10_000 * 0.02 / (1 + 0.02 * 6)
    assert abs(starts - expected) < 4.5 * math.sqrt(expected)


def test_window_and_ids_limit_the_fault():
    fault = BusFault("bus_off", (), 2.0, 0.5)  # ticks 200..249, every frame
    injector, out = run(fault, 400)
    lost = [tick for tick, copies in out if not copies]
    assert lost == list(range(200, 250))
    other = Injector((BusFault("drop", (0x101,), 0.0, 10.0),), RATE, 1, CODEC)
    assert all(other.transmit(t, SENSORS.frame_id, d) for t, d in frames(100))


def test_frozen_counter_has_a_valid_crc_and_is_repeated():
    fault = BusFault("freeze_counter", (SENSORS.frame_id,), 1.0, 0.3)
    _, out = run(fault, 200)
    checker = E2EChecker(SENSORS.data_id, max_delta=2)
    statuses = {}
    for tick, copies in out:
        (c,) = copies
        assert e2e_p01_check(bytearray(c.data), SENSORS.data_id)
        statuses[tick] = checker.check(c.data)
    window = range(101, 130)
    assert all(statuses[t] == E2EStatus.REPEATED for t in window)
    assert statuses[100] == E2EStatus.OK and statuses[99] == E2EStatus.OK
    assert statuses[131] == E2EStatus.OK  # counter moves on: within max_delta of the frozen one?


def test_delay_jitter_duplicate_reorder():
    delay = BusFault("delay", (SENSORS.frame_id,), 0.0, 10.0, delay_ticks=2, jitter_ticks=3)
    _, out = run(delay, 500)
    lags = [c.release_tick - tick for tick, copies in out for c in copies]
    assert set(lags) == {2, 3, 4, 5}
    dup = BusFault("duplicate", (SENSORS.frame_id,), 0.0, 10.0, rate=0.5)
    _, out = run(dup, 1000)
    twice = sum(len(copies) == 2 for _, copies in out)
    assert abs(twice - 500) < 4.5 * math.sqrt(250)
    reorder = BusFault("reorder", (SENSORS.frame_id,), 0.0, 10.0, rate=1.0)
    _, out = run(reorder, 10)
    order = [c.data[2] for _, copies in out for c in copies]
    assert order == [1, 0, 3, 2, 5, 4, 7, 6, 9, 8]


def test_babbling_node_floods_and_starves_lower_priority_frames():
    fault = BusFault("babble", (0x080,), 0.0, 1.0, flood_per_tick=5, starve=True)
    injector = Injector((fault,), RATE, 3, CODEC)
    flood = injector.flood(50)
    assert len(flood) == 5 and all(fid == 0x080 for fid, _, _ in flood)
    assert all(
        E2EChecker(CODEC["Demand"].data_id).check(d) == E2EStatus.WRONGCRC for _, d, _ in flood
    )
    assert injector.transmit(50, SENSORS.frame_id, b"\0" * 8) == []  # 0x100 loses arbitration
    assert injector.transmit(150, SENSORS.frame_id, b"\0" * 8)  # window over


def test_same_seed_same_faults_other_seed_other_faults():
    fault = BusFault("drop", (SENSORS.frame_id,), 0.0, 100.0, rate=0.1)
    a, _ = run(fault, 2000, seed=5)
    b, _ = run(fault, 2000, seed=5)
    c, _ = run(fault, 2000, seed=6)
    assert a.events == b.events
    assert a.events != c.events


@pytest.mark.parametrize(
    ("fault", "quiet_again"),
    [
        (BusFault("bus_off", (), 1.0, 0.5), 150),
        (BusFault("drop", (SENSORS.frame_id,), 1.0, 0.5, rate=0.5), 150),
        (BusFault("delay", (SENSORS.frame_id,), 1.0, 0.5, delay_ticks=2), 150),
        (BusFault("babble", (0x080,), 1.0, 0.5, starve=True), 150),
        # ticks 100..150, every other frame held: the one of tick 150 comes with tick 151's
        (BusFault("reorder", (SENSORS.frame_id,), 1.0, 0.51, rate=1.0), 152),
    ],
    ids=lambda f: getattr(f, "kind", ""),
)
def test_a_quiet_tick_passes_every_frame_unchanged_and_only_outside_the_window(fault, quiet_again):
    injector = Injector((fault,), RATE, 1, CODEC)
    quiet = []
    for tick, data in frames(300):
        if injector.quiet(tick):
            quiet.append(tick)
            events = len(injector.events)
            copies = injector.transmit(tick, SENSORS.frame_id, data)
            assert [(c.release_tick, c.data, c.event) for c in copies] == [(tick, data, None)]
            assert len(injector.events) == events
        else:
            injector.transmit(tick, SENSORS.frame_id, data)
    assert quiet == [*range(100), *range(quiet_again, 300)]
