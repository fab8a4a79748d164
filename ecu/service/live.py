"""The live-data record streamed by the service port: raw integers in a fixed order.

Each field has a unit and the scale that turns its raw integer into that unit (Q7.24 estimator
parameters and gains scale by 2**-24). The layout belongs to the protocol version: the host
decodes samples with this same table, and the stream's start response gives the field count.
"""

from __future__ import annotations

Q24 = 1.0 / (1 << 24)

# name, unit, scale (value = raw * scale)
FIELDS: tuple[tuple[str, str, float], ...] = (
    ("tick", "", 1.0),
    ("mode", "", 1.0),
    ("fault_word", "", 1.0),
    ("speed", "%N", 0.01),
    ("speed_rpm", "rpm", 1.0),
    ("speed_ref", "%N", 0.01),
    ("egt", "K", 0.1),
    ("pump_voltage", "V", 0.001),
    ("pump_duty", "%", 0.01),
    ("pump_enable", "", 1.0),
    ("supply", "V", 0.001),
    ("pump_current", "A", 0.001),
    ("pump_health", "%", 0.1),
    ("owner", "", 1.0),
    ("ap21", "1/s2", Q24),
    ("ap22", "1/s", Q24),
    ("lambda", "%N/(V s2)", Q24),
    ("theta21", "", Q24),
    ("theta22", "", Q24),
    ("kx1", "", Q24),
    ("kx2", "", Q24),
    ("kr", "", Q24),
    ("kf1", "", Q24),
    ("kf2", "", Q24),
    ("sat_events", "", 1.0),
    ("inputs_valid", "", 1.0),  # 1 once valid speed and EGT readings came since power-up
    ("seq_state", "", 1.0),  # start/stop sequencer step (ecu.start_sequencer.NAMES)
    ("seq_reason", "", 1.0),  # the last start's abort reason (ecu.start_sequencer.REASONS)
    ("seq_time", "s", 0.001),  # time in the step
    ("starter", "%", 0.01),
    ("igniter", "", 1.0),
    ("egt_start_limit", "K", 0.1),  # a start over it aborts (HOT_START)
    ("egt_start_target", "K", 0.1),  # the start's EGT target on the day
    ("demand", "%N", 0.01),  # the speed demand in force
    ("demand_source", "", 1.0),  # ecu.service.bench_demand: CAN, BENCH or NONE
)
NAMES = tuple(name for name, _, _ in FIELDS)


def sample(ecu, demand_source: int) -> list[int]:
    """The record of the ECU's last tick (``ecu.out``, ``ecu.s``, ``ecu.p``), in :data:`FIELDS`
    order, with the demand source the service port knows."""
    o = ecu.out
    s = ecu.s
    p = ecu.p
    return [
        s.ticks, o.mode, o.fault_word, o.n_cpct, s.speed_rpm, o.nref_cpct, s.egt_dk, o.pump_mv,
        o.duty_cpct, o.pump_enable, s.supply_mv, s.pump_ma, o.pump_health_pm, o.owner,
        o.ap21_q24, o.ap22_q24, o.lambda_q24, o.theta21_q24, o.theta22_q24,
        o.kx1_q24, o.kx2_q24, o.kr_q24, o.kf1_q24, o.kf2_q24, o.sat_events,
        o.inputs_valid, o.seq_state, o.seq_reason, s.seq_timer * 1000 // p.rate_hz,
        o.starter_cpct, o.igniter, p.seq_hot_dk, s.seq_target_dk,
        (s.demand_q24 * 100 + (1 << 23)) >> 24, demand_source,
    ]  # fmt: skip


def decode(raw: list[int]) -> dict[str, int | float]:
    """A sample in its units (counts and codes stay integers)."""
    return {
        name: r if scale == 1.0 else r * scale
        for (name, _, scale), r in zip(FIELDS, raw, strict=True)
    }
