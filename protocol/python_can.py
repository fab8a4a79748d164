"""python-can, imported without its MF4 classes.

python-can imports asammdf (and with it pandas) for its MF4 reader and writer whenever asammdf is
installed: about a second of every process's start here, and near a minute in an emulated
machine, for classes nothing of ours uses (MF4 logs go through :mod:`sil.record.mdf`, which
imports asammdf itself when a log is read or written). A command's entry point calls
:func:`import_without_mf4` before anything imports ``can``: asammdf is hidden while python-can
loads (python-can then goes on without MF4) and importable again right after.
"""

from __future__ import annotations

import sys


def import_without_mf4() -> None:
    """Import ``can`` with asammdf hidden; nothing when ``can`` or asammdf is loaded already."""
    if "can" in sys.modules or "asammdf" in sys.modules:
        return
    sys.modules["asammdf"] = None  # type: ignore[assignment]  (an import of it fails)
    try:
        import can  # noqa: F401
    finally:
        del sys.modules["asammdf"]
