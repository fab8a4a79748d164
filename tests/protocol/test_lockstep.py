from hypothesis import given
from hypothesis import strategies as st

from protocol.codec import Codec
from protocol.lockstep import TickEvent, TickTracker, every_ticks


def test_every_ticks_follows_dbc_cycle_times():
    codec = Codec()
    assert every_ticks(codec["PlantSensors"].cycle_time_ms, 100) == 1
    assert every_ticks(codec["Demand"].cycle_time_ms, 100) == 5
    assert every_ticks(codec["Demand"].cycle_time_ms, 1000) == 50
    assert every_ticks(codec["EcuTelemetry"].cycle_time_ms, 50) == 1


def test_tracker_classifies_and_counts():
    t = TickTracker()
    events = [t.observe(k) for k in (10, 11, 11, 14, 12, 15)]
    assert events == [
        TickEvent.NEXT,
        TickEvent.NEXT,
        TickEvent.REPEATED,
        TickEvent.SKIPPED,
        TickEvent.OUT_OF_ORDER,
        TickEvent.NEXT,
    ]
    assert (t.repeated, t.skipped, t.missing, t.out_of_order) == (1, 1, 2, 1)


@given(st.integers(0, 65535), st.integers(1, 200))
def test_tracker_wraps_at_16_bits(start, n):
    t = TickTracker()
    assert all(t.observe((start + i) % 65536) == TickEvent.NEXT for i in range(n))
    assert t.missing == 0
