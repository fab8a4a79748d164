"""The test tiers: the fast tier's list of slow modules names files that exist, and the fast tier
keeps most modules (a renamed module would otherwise fall out of the list, or in, unnoticed)."""

import importlib.util
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def _slow_modules() -> frozenset[str]:
    spec = importlib.util.spec_from_file_location("tiers_conftest", TESTS / "conftest.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.SLOW_MODULES


def test_every_slow_module_exists():
    missing = sorted(m for m in _slow_modules() if not (TESTS / m).is_file())
    assert not missing, f"SLOW_MODULES names files that are not there: {missing}"


def test_the_fast_tier_keeps_most_modules():
    slow = _slow_modules()
    modules = {p.relative_to(TESTS).as_posix() for p in TESTS.rglob("test_*.py")}
    assert slow < modules and len(modules - slow) > len(slow)
