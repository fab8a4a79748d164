"""How plant/ compiles with numba: the options of every compiled function, and an on-disk cache
kept consistent with the sources.

Options: cached compilation; numpy's error model (no Python-style division checks: the model
guards its denominators); and the fast-math flags that do not change what a float means (no
"nnan"/"ninf", so NaN checks still work): signed zeros, reciprocals, fused multiply-add and
approximate library functions. On the trim and a 15 s staircase these change the states by
less than 3e-15 relative and make the engine about 1.7 times faster.

Per-period code around the engine (pump driver, sensors, truth: plant/periphery.py) compiles with
EXACT instead: no fast-math at all, so that its arithmetic is the IEEE arithmetic Python does
and a compiled period gives the same bits as the Python it replaced. It calls the fast-math
engine as a separate compiled function, whose flags stay its own.

Cache: numba checks a cached function only against its own file, but the engine's compiled
step inlines component functions from other files. On import, a digest of every plant source is
compared with the one stored beside the cache; when they differ, the cached machine code of
plant/ is deleted and compiles afresh on first use.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from pathlib import Path

JIT = {"cache": True, "error_model": "numpy", "fastmath": {"nsz", "arcp", "contract", "afn"}}
EXACT = {"cache": True, "error_model": "numpy"}

PLANT_DIR = Path(__file__).resolve().parent
CACHE_DIR = PLANT_DIR / "__pycache__"
STAMP = CACHE_DIR / "numba-sources.sha256"


def source_digest(sources: Iterable[Path]) -> str:
    """SHA-256 over the names and bytes of ``sources``."""
    h = hashlib.sha256()
    for path in sorted(sources):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def keep_cache_fresh(cache_dir: Path, stamp: Path, cached: str, sources: Iterable[Path]) -> None:
    """Delete the cached machine code matching ``cached`` (a glob of numba's index and data files
    without their suffix) in ``cache_dir`` unless ``stamp`` holds the digest of ``sources``;
    then store the digest. For compiled code that inlines or links functions of other files."""
    digest = source_digest(sources)
    try:
        if stamp.read_text() == digest:
            return
    except OSError:
        pass
    for suffix in ("nbi", "nbc"):
        for path in cache_dir.glob(f"{cached}.{suffix}"):
            path.unlink(missing_ok=True)
    try:
        cache_dir.mkdir(exist_ok=True)
        stamp.write_text(digest)
    except OSError:
        pass  # read-only install: numba then caches elsewhere or not at all


def ensure_fresh() -> None:
    keep_cache_fresh(CACHE_DIR, STAMP, "*", sorted(PLANT_DIR.glob("*.py")))
