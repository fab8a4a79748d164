"""The command node ends the run on the ECU's answer to the last tick, and the log is the same
whichever order the plant's and the ECU's frames of that tick reached it."""

import numpy as np

from protocol.codec import Codec
from sil.record.recorder import Recorder
from sil.run.command_node import CommandNode

TICKS = 12  # commands for ticks 0..11


def _frames(codec: Codec, k: int) -> dict[str, tuple[int, bytes]]:
    out = {}
    for name, values in (
        ("PlantSensors", [k, 100_000, 1000.0]),
        ("EcuTelemetry", [k % 13, 0.5]),
        ("EcuActuator", [1, 2, k, 50.0, 6.0]),
    ):
        m = codec[name]
        m.pack(values)
        out[name] = (m.frame_id, bytes(m.data))
    return out


def _play(tmp_path, name: str, sequence: list[tuple[int, bytes]]) -> tuple[str, CommandNode]:
    out = tmp_path / name
    out.mkdir()
    codec = Codec()
    rec = Recorder(out, codec, period_s=0.01)
    node = CommandNode(codec, rec, np.full(TICKS, 90.0), ecu_rate_hz=100.0, open_loop=False)
    sent: list[tuple[int, bytes]] = []
    node.start(lambda frame_id, data: sent.append((frame_id, bytes(data))))
    for frame_id, data in sequence:  # as the listening loop does: stop once finished
        node.on_frame(frame_id, data, lambda i, d: sent.append((i, bytes(d))))
        if node.finished:
            break
    rec.close()
    return (out / "can.log").read_text(), node


def test_the_last_tick_answered_before_its_sensor_frame_ends_the_run_all_the_same(tmp_path):
    codec = Codec()
    ticks = [_frames(codec, k) for k in range(TICKS + 1)]  # the plant runs one tick further
    order = ("PlantSensors", "EcuTelemetry", "EcuActuator")
    in_order = [t[n] for t in ticks for n in order]
    last = TICKS - 1
    # the ECU's answer to the last tick reaches the recorder before PlantSensors(last), and the
    # ECU's first frame of the next tick follows at once
    raced = [t[n] for t in ticks[:last] for n in order]
    raced += [ticks[last]["EcuTelemetry"], ticks[last]["EcuActuator"]]
    raced += [ticks[last]["PlantSensors"], ticks[last + 1]["PlantSensors"]]
    raced += [ticks[last + 1]["EcuTelemetry"], ticks[last + 1]["EcuActuator"]]
    log_a, node_a = _play(tmp_path, "a", in_order)
    log_b, node_b = _play(tmp_path, "b", raced)
    assert node_a.finished and node_b.finished
    assert log_a == log_b
    assert log_a.count("vcan0 110#") == TICKS  # the actuator of every tick, none beyond
    assert log_a.count("vcan0 210#") == TICKS
