"""What the page takes from the project's A2L, read by pya2ldb as the field's tools read it:
each parameter's address, limits, unit and conversion as the ECU's parameter table has them,
the curves with their points, and the logbook's enumeration by its names."""

from __future__ import annotations

import gc
import sys
import threading
from pathlib import Path

import pytest

from ecu.logbook import SHUTDOWN_NAMES
from ecu.service.param_table import TABLE
from ecu.xcp import memory as MEM
from ecu.xcp.a2l import a2l_text
from ecu.xcp.slave import Limits
from sil.console.gsu.xcp_link import physical
from sil.record.a2l import read_a2l


@pytest.fixture(scope="module")
def a2l(tmp_path_factory):  # noqa: ANN201
    path = Path(tmp_path_factory.mktemp("a2l")) / "turbojet_ecu.a2l"
    path.write_text(a2l_text(100, (0x700, 0x701), Limits()), "latin-1")
    return read_a2l(path)


def test_every_value_parameter_as_the_ecu_table_has_it(a2l) -> None:  # noqa: ANN001
    chars = a2l.characteristics
    checked = 0
    for k, spec in enumerate(TABLE):
        if spec.element is not None or spec.name not in chars:
            continue  # (a pair's or a curve's point: the curve is one characteristic)
        c = chars[spec.name]
        assert c.kind == "VALUE" and c.address == MEM.parameter_address(k), spec.name
        assert (c.lower, c.upper) == pytest.approx((spec.lo, spec.hi)), spec.name
        assert c.to_raw(spec.lo) == spec.to_raw(spec.lo), spec.name
        assert c.to_value(spec.raw_hi) == pytest.approx(spec.to_value(spec.raw_hi)), spec.name
        checked += 1
    assert checked > 40


def test_curves_and_the_bench_words(a2l) -> None:  # noqa: ANN001
    curve = a2l.characteristics["accel_line_v"]
    assert (curve.kind, curve.count, curve.datatype, curve.unit) == ("CURVE", 12, "SLONG", "V")
    assert a2l.characteristics["bench_stop"].address == MEM.bench_address(MEM.BENCH_STOP)


def test_the_logbook_enumeration_reads_by_name(a2l) -> None:  # noqa: ANN001
    conversion = a2l.measurements["log_last_shutdown"].conversion
    assert [physical(k, conversion) for k in range(len(SHUTDOWN_NAMES))] == list(SHUTDOWN_NAMES)
    assert physical(1250, {"a": 0.1, "b": 0.0}) == pytest.approx(125.0)
    assert physical(7, None) == 7


def test_an_a2l_read_in_one_thread_leaves_nothing_for_another(tmp_path) -> None:
    """The page reads its A2L in a worker thread: pya2ldb's SQLite database is closed there,
    not by the collector in whichever thread it runs (SQLite refuses that with a traceback)."""
    path = tmp_path / "turbojet_ecu.a2l"
    path.write_text(a2l_text(100, (0x700, 0x701), Limits()), "latin-1")
    read = threading.Thread(target=read_a2l, args=(path,))
    raised: list[str] = []
    hook, sys.unraisablehook = sys.unraisablehook, lambda u: raised.append(repr(u.exc_value))
    try:
        read.start()
        read.join()
        gc.collect()
    finally:
        sys.unraisablehook = hook
    assert raised == []
