"""Run tags: the wire IDs of a run and the claims of tags on a bus."""

import os
import signal
import subprocess
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.run_tag import DBC_ID_MASK, MAX_TAG, claim_tag, split_id, tag_dir, wire_id

tags = st.integers(0, MAX_TAG)
dbc_ids = st.integers(0, DBC_ID_MASK)


@given(tags, dbc_ids)
def test_wire_ids_map_back_to_the_run_and_its_dbc_id(tag, dbc_id):
    wire, extended = wire_id(tag, dbc_id)
    assert extended == (tag != 0)
    assert wire <= (0x1FFFFFFF if extended else 0x7FF)
    assert split_id(wire, extended) == (tag, dbc_id)


@given(tags, dbc_ids, tags, dbc_ids)
def test_runs_never_share_a_wire_id(tag_a, id_a, tag_b, id_b):
    if (tag_a, id_a) != (tag_b, id_b):
        assert wire_id(tag_a, id_a) != wire_id(tag_b, id_b)


def test_the_primary_run_sends_the_dbc_ids_as_they_are():
    assert wire_id(0, 0x100) == (0x100, False)
    assert wire_id(3, 0x100) == (3 << 11 | 0x100, True)


@pytest.mark.parametrize("wire", [0x100, (MAX_TAG + 1) << 11 | 0x100, 0x1FFFFFFF])
def test_extended_ids_of_no_run_are_not_taken_for_one(wire):
    assert split_id(wire, extended=True) is None


@pytest.mark.parametrize("tag, dbc_id", [(-1, 0), (MAX_TAG + 1, 0), (0, 0x800)])
def test_no_wire_id_outside_the_ranges(tag, dbc_id):
    with pytest.raises(ValueError):
        wire_id(tag, dbc_id)


@pytest.fixture
def runtime_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    return tmp_path


def test_runs_on_one_bus_get_different_tags_and_give_them_back(runtime_dir):
    with claim_tag("udp:239.255.1.2@43113") as first, claim_tag("udp:239.255.1.2@43113") as second:
        assert (first.tag, second.tag) == (0, 1)
        with claim_tag("socketcan:vcan0") as other_bus:
            assert other_bus.tag == 0
    with claim_tag("udp:239.255.1.2@43113") as again:
        assert again.tag == 0
    assert list(tag_dir().iterdir()) == []  # a run that ends removes its file


def test_buses_whose_names_differ_only_in_punctuation_have_their_own_tags(runtime_dir):
    with (
        claim_tag("virtual:a_b") as a,
        claim_tag("virtual:a/b") as b,
        claim_tag("virtual:a:b") as c,
    ):
        assert (a.tag, b.tag, c.tag) == (0, 0, 0)


def test_a_killed_process_gives_its_tag_back(runtime_dir):
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from protocol.run_tag import claim_tag; "
            "c = claim_tag('virtual:x'); print(c.tag, flush=True); time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "XDG_RUNTIME_DIR": str(runtime_dir)},
    )
    try:
        assert holder.stdout.readline().strip() == "0"
        with claim_tag("virtual:x") as claim:
            assert claim.tag == 1
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    with claim_tag("virtual:x") as claim:
        assert claim.tag == 0
