"""The XCP identifiers: in the DBC as two raw 8-byte messages that clash with no other ID, left
out of the codec's signal messages, and the ECU's --xcp-ids checked against the contract."""

from __future__ import annotations

import pytest

from protocol.codec import Codec
from protocol.dbc import is_xcp, load_database, xcp_frame_ids
from protocol.run_tag import wire_id


def test_the_xcp_messages_clash_with_no_other_id():
    db = load_database()
    ids = [m.frame_id for m in db.messages]
    assert len(ids) == len(set(ids))
    cmd, res = xcp_frame_ids(db)
    assert (cmd, res) == (0x700, 0x701)
    xcp = {m.name: m for m in db.messages if is_xcp(m)}
    assert set(xcp) == {"XcpCommand", "XcpResponse"}
    assert xcp["XcpCommand"].senders == ["XcpMaster"] and xcp["XcpResponse"].senders == ["ECU"]
    for m in xcp.values():
        assert m.length == 8 and [s.length for s in m.signals] == [64]
        assert not m.is_extended_frame
    # the primary run (tag 0) sends them as they are: standard IDs on the wire
    assert wire_id(0, cmd) == (cmd, False) and wire_id(0, res) == (res, False)


def test_the_codec_leaves_the_xcp_packets_out():
    names = {m.name for m in Codec().messages}
    assert "XcpCommand" not in names and "XcpResponse" not in names and "EcuStatus" in names


@pytest.mark.parametrize(
    ("ids", "why"),
    [
        ("0x700", "two CAN IDs"),
        ("0x700,0x700", "two different"),
        ("0x700,0x800", "two different standard IDs"),
        ("0x100,0x701", "PlantSensors's ID"),
        ("0x7F0,0x701", "SimRun's ID"),
        ("x,y", "two CAN IDs"),
    ],
)
def test_ecu_refuses_xcp_ids_that_clash_or_are_not_ids(sil, ids, why):
    result = sil("ecu", "--bus", "virtual:ids", "--xcp-ids", ids, "--ticks", "1")
    assert result.returncode == 2 and why in result.stderr


def test_xcp_ids_need_a_slave(sil):
    result = sil("ecu", "--bus", "virtual:ids", "--no-xcp", "--xcp-ids", "0x600,0x601")
    assert result.returncode == 2 and "no XCP slave runs" in result.stderr
    serial = ("--impl", "c", "--serial", "pty", "--xcp-ids", "0x600,0x601")
    result = sil("ecu", "--bus", "virtual:ids", *serial, "--ticks", "1")
    assert result.returncode == 2 and "--impl c with --serial" in result.stderr


def test_the_c_node_takes_xcp_ids(sil):
    result = sil(
        "ecu", "--bus", "virtual:ids", "--impl", "c", "--xcp-ids", "0x600,0x601", "--ticks", "1",
        "--mode", "realtime",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "xcp: CAN IDs 0x600 (master) 0x601 (ECU)" in result.stderr
