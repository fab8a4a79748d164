"""`sil bench pil` without the Arm toolchain or QEMU: it says which tool is missing and how to
install it, before it starts any run (whose ecu.log, telling the same, goes with its folder)."""

from __future__ import annotations

import shutil

import pytest

from ecu.port.build import ARM_CC
from ecu.port.qemu import QEMU
from sil.bench import pil as pil_bench
from sil.bench.common import BenchError


def test_a_missing_qemu_is_named_before_any_run(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(shutil, "which", lambda tool: None if tool == QEMU else f"/usr/bin/{tool}")
    monkeypatch.setattr(pil_bench, "completed_run", lambda *a: pytest.fail("a run started"))
    with pytest.raises(BenchError, match=f"{QEMU} not found .*apt-get install") as err:
        pil_bench.run(quick=True)
    assert ARM_CC not in str(err.value)  # the compiler is there: only QEMU is named
