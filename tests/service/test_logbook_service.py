"""The service port's logbook read: the firmware's logbook words, in ecu.logbook's order, in a
frame at any count."""

from __future__ import annotations

from ecu import logbook as L
from ecu.fixedpoint import INT32_MAX
from ecu.service.message import Service


def test_the_logbook_is_read_as_the_firmware_holds_it(rig):
    rig.ticks(2)
    assert rig.client.request(Service.LOGBOOK_READ) == [0] * len(L.word_names())
    s = rig.ecu.s
    s.log_runs, s.log_run_time_s, s.log_starts = 3, 4567, 5
    s.log_aborts[1] = 2
    s.log_last_max_egt_dk, s.log_last_shutdown = 10321, L.SD_FLAMEOUT
    got = dict(zip(L.word_names(), rig.client.request(Service.LOGBOOK_READ), strict=True))
    assert got == L.stored_dict(s)
    assert got["log_aborts_slow_accel"] == 2 and got["log_last_shutdown"] == L.SD_FLAMEOUT


def test_a_full_logbook_fits_a_frame(rig):
    s = rig.ecu.s
    for name in L.STORED:
        if name == "log_aborts":
            for k in range(L.N_ABORTS):
                s.log_aborts[k] = INT32_MAX
        else:
            setattr(s, name, INT32_MAX)
    assert rig.client.request(Service.LOGBOOK_READ) == [INT32_MAX] * len(L.word_names())
