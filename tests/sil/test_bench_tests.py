"""`sil bench tests` reads each part of the suite from pytest's own last line: checked against
pytest's real output for a small suite with a pass, a failure, an error, a skip and a deselected
test, and for a part that collected nothing."""

from __future__ import annotations

import subprocess
import sys

from sil.bench.tests import parts

SUITE = """
import pytest

@pytest.fixture
def broken():
    raise RuntimeError("set-up fails")

def test_passes():
    pass

def test_passes_too():
    pass

def test_fails():
    assert False

def test_errors(broken):
    pass

@pytest.mark.skip(reason="not here")
def test_skipped():
    pass

def test_left_out():
    pass
"""


def _pytest(folder, *args: str) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "--rootdir", str(folder),
         "-c", str(folder / "pytest.ini"), str(folder), *args],
        capture_output=True, text=True, cwd=folder,
    )  # fmt: skip
    return done.stdout


def test_the_counts_and_seconds_are_pytests(tmp_path):
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    (tmp_path / "test_small.py").write_text(SUITE)
    (found,) = parts(_pytest(tmp_path, "-k", "not left_out"))
    assert {k: v for k, v in found.items() if k != "seconds"} == {
        "passed": 2, "failed": 1, "error": 1, "skipped": 1, "deselected": 1,
    }  # fmt: skip
    assert 0 <= found["seconds"] < 60


def test_two_parts_one_of_which_ran_nothing(tmp_path):
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    (tmp_path / "test_small.py").write_text(SUITE)
    output = _pytest(tmp_path, "-k", "passes") + _pytest(tmp_path, "-k", "nothing_matches")
    first, second = parts(output)
    assert first["passed"] == 2 and first["deselected"] == 4
    assert second.get("passed", 0) == 0 and second["deselected"] == 6
