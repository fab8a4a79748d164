"""The DBC loads cleanly and describes every frame the contract needs."""

import warnings

import cantools
import pytest

from protocol.codec import Codec
from protocol.dbc import DBC_PATH, ContractError, load_database, message_attribute

REQUIRED = {
    "PlantSensors": ("Plant", {"ShaftSpeed", "EGT", "SensorTick"}),
    "PlantAnalog": ("Plant", {"SupplyVoltage", "PumpCurrent"}),
    "EcuActuator": ("ECU", {"PumpDuty", "PumpVoltageTarget", "PumpEnable", "ActuatorMode"}),
    "Demand": ("Command", {"SpeedDemand", "ArmRequest", "StopRequest"}),
    "EcuStatus": ("ECU", {"EcuMode", "FaultWord", "PumpHealth"}),
    "EcuTelemetry": (
        "ECU",
        {
            "Est_Ap21",
            "Est_Ap22",
            "Est_Lambda",
            "Est_Theta21",
            "Est_Theta22",
            "Gain_Kx1",
            "Gain_Kx2",
            "Gain_Kr",
            "Gain_Kf1",
            "Gain_Kf2",
        },
    ),
    "PlantTruthA": ("Plant", {"P3", "P5", "T4"}),
    "PlantTruthB": ("Plant", {"FuelFlow", "Thrust"}),
    "FaultInject": ("Command", {"FaultTarget", "FaultTick", "FaultValue"}),
    "EcuStarter": ("ECU", {"StarterDuty", "IgniterOn", "SequencerState", "AbortReason"}),
    "PlantTruthC": ("Plant", {"Burning", "HotSectionTemp", "StarterCurrent", "UnburntFuel"}),
}


def test_loads_strictly_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        db = cantools.database.load_file(str(DBC_PATH), strict=True)
    assert {m.name for m in db.messages} >= set(REQUIRED)


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_message_has_sender_cycle_and_signals(name):
    db = load_database()
    message = db.get_message_by_name(name)
    sender, signals = REQUIRED[name]
    assert message.senders == [sender]
    assert signals <= {s.name for s in message.signals}
    assert all(s.receivers for s in message.signals)
    assert message_attribute(message, "GenMsgCycleTime") is not None
    if name != "FaultInject":
        assert message.cycle_time and message.cycle_time > 0


def test_signal_resolutions_meet_the_contract():
    db = load_database()
    sig = {s.name: s for m in db.messages for s in m.signals}
    assert sig["ShaftSpeed"].scale <= 1 and sig["ShaftSpeed"].maximum >= 150_000
    assert sig["EGT"].scale <= 0.1
    assert sig["PumpDuty"].scale <= 0.1
    assert sig["PumpVoltageTarget"].scale <= 0.001  # mV
    assert sig["SpeedDemand"].scale <= 0.01


def test_simulation_only_and_e2e_marks():
    codec = Codec()
    assert {m.name for m in codec.messages if m.sim_only} == {
        "PlantTruthA",
        "PlantTruthB",
        "PlantTruthC",
        "FaultInject",
        "SimRun",
    }
    protected = [m for m in codec.messages if m.protected]
    # every frame with a command or a sensor value is protected, each with its own data ID
    commands = {"Demand", "PlantSensors", "PlantAnalog", "EcuActuator", "EcuStarter"}
    assert commands <= {m.name for m in protected}
    assert len({m.data_id for m in protected}) == len(protected)


def test_sequencer_names_are_the_firmwares():
    """The DBC's value tables for the sequencer's state and abort reason name the firmware's."""
    from ecu import start_sequencer as seq

    db = load_database()
    m = db.get_message_by_name("EcuStarter")
    state, reason = m.get_signal_by_name("SequencerState"), m.get_signal_by_name("AbortReason")
    assert [str(state.choices[i]) for i in range(len(seq.NAMES))] == list(seq.NAMES)
    assert [str(reason.choices[i]) for i in range(len(seq.REASONS))] == list(seq.REASONS)
    fault = db.get_message_by_name("FaultInject").get_signal_by_name("FaultTarget")
    assert {str(fault.choices[k]) for k in (13, 14, 15)} == {
        "IGNITER_FAILURE", "STARTER_FAILURE", "FUEL_STARVATION",
    }  # fmt: skip


def test_broken_dbc_is_one_clear_error(tmp_path):
    bad = tmp_path / "bad.dbc"
    bad.write_text(
        DBC_PATH.read_text().replace(
            "BO_ 256 PlantSensors: 8 Plant", "BO_ 256 PlantSensors 8 Plant"
        )
    )
    with pytest.raises(ContractError, match="bad.dbc"):
        load_database(bad)
    with pytest.raises(ContractError, match="not found"):
        load_database(tmp_path / "missing.dbc")
