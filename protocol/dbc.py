"""The DBC file: single source of truth for every frame on the bus."""

from __future__ import annotations

import warnings
from pathlib import Path

import cantools
from cantools.database.can import Database

DBC_PATH = Path(__file__).with_name("turbojet.dbc")


class ContractError(Exception):
    """The CAN contract (DBC) could not be loaded or is inconsistent."""


def load_database(path: str | Path = DBC_PATH) -> Database:
    """Load the DBC strictly; any error or warning becomes one :class:`ContractError` line."""
    path = Path(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            db = cantools.database.load_file(str(path), database_format="dbc", strict=True)
    except FileNotFoundError:
        raise ContractError(f"{path}: DBC file not found") from None
    except Exception as exc:  # cantools raises several parser error types
        raise ContractError(f"{path}: DBC failed to load: {exc}") from exc
    if not isinstance(db, Database):
        raise ContractError(f"{path}: not a CAN database")
    return db


def message_attribute(message, name: str, default: int | str = 0) -> int | str:
    """A DBC message attribute (GenMsgCycleTime, E2EDataID, SimulationOnly...) or its default."""
    attrs = message.dbc.attributes if message.dbc is not None else {}
    if name in attrs:
        return attrs[name].value
    definitions = message.dbc.attribute_definitions if message.dbc is not None else {}
    return definitions[name].default_value if name in definitions else default


def is_xcp(message) -> bool:
    """A message of the XCP transport (attribute ``Transport`` = XCP): raw XCP packets, not
    signals of the contract; the codec leaves them out."""
    return message_attribute(message, "Transport", "None") in (1, "XCP")


def xcp_frame_ids(db: Database | None = None) -> tuple[int, int]:
    """The XCP identifiers the DBC gives: (master to ECU, ECU to master)."""
    db = db or load_database()
    messages = [m for m in db.messages if is_xcp(m)]
    to_ecu = [m.frame_id for m in messages if "ECU" not in m.senders]
    from_ecu = [m.frame_id for m in messages if "ECU" in m.senders]
    if len(to_ecu) != 1 or len(from_ecu) != 1:
        raise ContractError("the DBC needs one XCP message to the ECU and one from it")
    return to_ecu[0], from_ecu[0]
