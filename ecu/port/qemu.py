"""Run the Cortex-M4 replayer under QEMU (mps2-an386, semihosting for the file and the output)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

QEMU = "qemu-system-arm"
MACHINE = "mps2-an386"
QEMU_NOT_FOUND = f"{QEMU} not found (apt-get install qemu-system-arm)"


def command(*, icount: bool) -> list[str]:
    """QEMU on the board, no display and no monitor (``icount``: the virtual clock advances one
    ns per instruction)."""
    return [QEMU, "-M", MACHINE, *(("-icount", "shift=0") if icount else ()), "-nographic",
            "-monitor", "none"]  # fmt: skip


def run(elf: Path, vectors: Path, *, icount: bool = False, timeout: float = 300.0):  # noqa: ANN201
    """``replay VECTORS`` on the emulated board; returns the CompletedProcess (text output)."""
    if not shutil.which(QEMU):
        raise FileNotFoundError(QEMU_NOT_FOUND)
    cmd = [
        *command(icount=icount),
        "-serial",
        "none",
        "-semihosting-config",
        # commas separate QEMU sub-options: a comma in the path is written twice
        f"enable=on,target=native,arg=replay,arg={str(vectors.resolve()).replace(',', ',,')}",
        "-kernel",
        str(elf),
    ]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
