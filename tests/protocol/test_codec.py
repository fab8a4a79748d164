"""The struct codec agrees bit for bit with cantools over the full range of every signal."""

import sys

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.codec import Codec, MessageCodec

CODEC = Codec()
DB = CODEC.database


def _cantools_values(message: MessageCodec, names, raws) -> dict:
    """Physical values for cantools, including the E2E fields our codec filled in."""
    cm = DB.get_message_by_frame_id(message.frame_id)
    values = dict(zip(names, raws, strict=True))
    if message.protected:
        crc_name = next(s.name for s in cm.signals if s.name.endswith("_CRC"))
        cnt_name = next(s.name for s in cm.signals if s.name.endswith("_Counter"))
        values[crc_name] = message.data[0]
        values[cnt_name] = message.data[1] & 0x0F
    return values


def _names(message: MessageCodec, raws) -> tuple[str, ...]:
    if message.multiplexed:
        return (message.signal_names[0], message.mux_signals[raws[0]].name)
    return message.signal_names


@st.composite
def message_and_raws(draw):
    message = draw(st.sampled_from(CODEC.messages))
    if message.multiplexed:
        mux = draw(st.sampled_from(sorted(message.mux_signals)))
        layout = message.mux_signals[mux]
        return message, [mux, draw(st.integers(layout.raw_min, layout.raw_max))]
    return message, [draw(st.integers(s.raw_min, s.raw_max)) for s in message.signals]


@settings(max_examples=600, deadline=None)
@given(message_and_raws())
def test_raw_round_trip_equals_cantools(case):
    message, raws = case
    assert message.pack_raw(raws) == 0
    frame = bytes(message.data)
    names = _names(message, raws)
    cm = DB.get_message_by_frame_id(message.frame_id)
    # cantools encodes the same raw values to the same bytes...
    raw_values = _cantools_values(message, names, raws)
    assert cm.encode(raw_values, scaling=False, strict=True) == frame
    # ...and decodes our frame to the same raw values
    decoded = cm.decode(frame, scaling=False, decode_choices=False)
    assert [decoded[n] for n in names] == raws
    out = [0] * len(raws)
    message.unpack_raw(frame, out)
    assert out == raws


@settings(max_examples=400, deadline=None)
@given(message_and_raws())
def test_physical_values_agree_with_cantools(case):
    message, raws = case
    layouts = (
        message.signals
        if not message.multiplexed
        else (message.mux_layout, message.mux_signals[raws[0]])
    )
    physical = [layout.to_physical(r) for layout, r in zip(layouts, raws, strict=True)]
    assert message.pack(physical) == 0
    frame = bytes(message.data)
    cm = DB.get_message_by_frame_id(message.frame_id)
    names = _names(message, raws)
    assert cm.encode(_cantools_values(message, names, physical), strict=True) == frame
    decoded = cm.decode(frame, decode_choices=False)
    out = [0.0] * len(raws)
    message.unpack(frame, out)
    assert out == pytest.approx([decoded[n] for n in names], rel=1e-12, abs=1e-12)


@given(st.floats(allow_nan=False, allow_infinity=False, min_value=-1e9, max_value=1e9))
def test_out_of_range_saturates_and_is_flagged(speed):
    sensors = CODEC["PlantSensors"]
    saturated = sensors.pack([7, speed, 1000.0])
    out = [0.0, 0.0, 0.0]
    sensors.unpack(sensors.data, out)
    if speed < -0.5:
        assert saturated == 0b010 and out[1] == 0
    elif speed > 150_000.5:
        assert saturated == 0b010 and out[1] == 150_000  # saturated, never wrapped
    else:  # within half a step of the range: rounds onto it
        assert saturated == 0 and out[1] == min(max(round(speed), 0), 150_000)
    assert out[0] == 7 and out[2] == 1000.0


def test_raw_saturation_of_signed_and_multiplexed_values():
    telemetry = CODEC["EcuTelemetry"]
    assert telemetry.pack_raw([3, -(1 << 40)]) == 0b10
    out = [0, 0]
    telemetry.unpack_raw(telemetry.data, out)
    assert out == [3, -(1 << 31)]
    with pytest.raises(ValueError, match="multiplexer index 99"):
        telemetry.pack_raw([99, 0])


def test_nan_and_wrong_arity_are_refused():
    sensors = CODEC["PlantSensors"]
    with pytest.raises(ValueError, match="EGT: value is NaN"):
        sensors.pack([1, 1000, float("nan")])
    with pytest.raises(ValueError, match="expected 3 values"):
        sensors.pack_raw([1, 2])


def test_pack_and_unpack_allocate_nothing_that_stays():
    codec = Codec()
    sensors, telemetry = codec["PlantSensors"], codec["EcuTelemetry"]
    out3, out2 = [0, 0, 0], [0, 0]
    raws3, raws2 = [100, 90_000, 10_300], [4, 123_456]

    def work(n):
        for i in range(n):
            raws3[0] = i & 0xFFFF
            sensors.pack_raw(raws3)
            sensors.unpack_raw(sensors.data, out3)
            telemetry.pack_raw(raws2)
            telemetry.unpack_raw(telemetry.data, out2)

    work(2000)
    before = sys.getallocatedblocks()
    work(50_000)
    assert sys.getallocatedblocks() - before < 10
