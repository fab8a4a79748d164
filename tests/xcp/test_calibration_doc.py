"""The pyXCP session of docs/calibration.md, as it is written there, against a real-time plant
at rest and `sil ecu` on the loopback bus: it prints what the page says and records its CSV."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

DOC = Path(__file__).resolve().parents[2] / "docs" / "calibration.md"
MARKER = "<!-- the test tests/xcp/test_calibration_doc.py runs this script against a bench -->"


def _script() -> str:
    text = DOC.read_text()
    after = text[text.index(MARKER) + len(MARKER) :]
    return re.search(r"```python\n(.*?)```", after, re.S).group(1)


@pytest.mark.slow
def test_the_documented_session_runs_as_documented(tmp_path, udp_group):
    group, port = udp_group
    (tmp_path / "xcp_session.py").write_text(_script())
    sil = [sys.executable, "-m", "sil.cli"]
    done = subprocess.run([*sil, "a2l", "--out", str(tmp_path / "turbojet_ecu.a2l")])
    assert done.returncode == 0
    bus = f"udp:{group}@{port}"
    plant = subprocess.Popen(
        [*sil, "plant", "--bus", bus, "--realtime", "--standstill"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    ecu = subprocess.Popen(
        [*sil, "ecu", "--bus", bus, "--mode", "realtime", "--flash", str(tmp_path / "ecu.flash")],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert ecu.stderr.readline().startswith("xcp: CAN IDs 0x700")
        time.sleep(2)  # the plant's first frames
        session = subprocess.run(
            [sys.executable, "xcp_session.py", "turbojet_ecu.a2l", group, str(port)],
            cwd=tmp_path, capture_output=True, text=True, timeout=120,
        )  # fmt: skip
    finally:
        for proc in (ecu, plant):
            proc.terminate()
            proc.wait(20)
    assert session.returncode == 0, session.stderr[-3000:]
    said = ("ECU: ", "egt_limit_k", "refused: ", "stored", "recorded ")  # (pya2ldb logs too)
    lines = [line for line in session.stdout.splitlines() if line.startswith(said)]
    assert lines[0].startswith("ECU: turbojet-ecu 0.1 build ") and "A2L: turbojet_ecu" in lines[0]
    assert lines[1:] == [
        "egt_limit_k = 1280 K",
        "egt_limit_k = 1250 K after the write",
        "refused: ERR_OUT_OF_RANGE",
        "stored",
        "recorded measurements.csv",
    ]
    rows = (tmp_path / "measurements.csv").read_text().splitlines()
    assert rows[0].split(",")[:2] == ["timestamp0", "timestamp1"] and len(rows) > 400
