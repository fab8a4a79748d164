"""The recorder asks the slave's DAQ info again when an answer was lost on a loaded bus (pyXCP
marks the info incomplete and does not ask again), and gives up after three incomplete answers."""

from __future__ import annotations

import pytest

from sil.record import xcp_record


class _Master:
    """pyXCP's getDaqInfo as a lossy bus leaves it: the first ``lost`` answers incomplete."""

    def __init__(self, lost: int) -> None:
        self.lost = lost
        self.asked = 0

    def getDaqInfo(self, include_event_lists: bool) -> dict:  # noqa: N802 (pyXCP's name)
        assert include_event_lists is False
        self.asked += 1
        complete = self.asked > self.lost
        return {"processor": {"minDaq": 0}, "resolution": {"timestampTicks": 1},
                "valid": {"processor": complete, "resolution": True}}  # fmt: skip


@pytest.mark.parametrize("lost", [0, 1, 2])
def test_a_lost_daq_info_answer_is_asked_again(lost):
    x = _Master(lost)
    info = xcp_record._daq_info(x)
    assert info["valid"]["processor"] and x.asked == lost + 1


def test_three_incomplete_answers_are_a_refusal():
    x = _Master(3)
    with pytest.raises(RuntimeError, match="3 attempts"):
        xcp_record._daq_info(x)
    assert x.asked == 3
