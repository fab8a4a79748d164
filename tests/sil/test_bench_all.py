"""`sil bench all`: every bench in one run, the machine named, each bench's targets, and the page
docs/benchmarks.md holding exactly the figures the benches printed."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import pytest

from sil.bench.suite import markdown, run_all, targets_of


@pytest.fixture
def sil(sil):
    """tests/conftest.py's ``sil`` with no time limit of its own for a command."""
    return functools.partial(sil, timeout=None)


def test_all_writes_the_page_with_every_figure_and_target(tmp_path: Path, sil) -> None:
    page = tmp_path / "benchmarks.md"
    done = sil("bench", "all", "--only", "codec,ecu", "--markdown", str(page), "--json")
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["mode"] == "quick" and result["machine"]["cores"] >= 1
    assert result["machine"]["cpu"]
    assert list(result["benches"]) == ["codec", "ecu"]
    text = page.read_text()
    assert "## Machine" in text and result["machine"]["cpu"] in text
    for name, entry in result["benches"].items():
        assert entry["targets_met"], f"{name} states no target"
        assert f"## `sil bench {name}`" in text
        for key, value in entry["figures"].items():
            if key != "targets_met":
                shown = f"{value:g}" if isinstance(value, float) else str(value)
                assert f"| `{key}` | {shown} |" in text, key
        for target, met in entry["targets_met"].items():
            stated = entry["target_text"][target]  # each target in words, from its bench
            assert f"| {name} | {stated} | {'yes' if met else '**no**'} |" in text
    assert result["benches"]["ecu"]["targets_met"]["no_allocation_per_tick"]


def test_a_failing_bench_is_reported_and_the_others_still_run() -> None:
    result = run_all({"broken": "sil.no_such_bench", "codec": "protocol.bench"})
    assert "ModuleNotFoundError" in result["benches"]["broken"]["error"]
    assert result["benches"]["codec"]["figures"]["codec_encode_us"] > 0
    assert "The bench failed" in markdown(result)


def test_targets_are_read_from_the_benches_verdicts() -> None:
    assert targets_of({"x": 1, "targets_met": {"a": True, "b": 0}}) == {"a": True, "b": False}
    assert targets_of({"flash_target_met": True, "targets_met": False}) == {
        "flash": True,
        "targets": False,
    }


def test_options_of_all_are_checked(sil) -> None:
    assert sil("bench", "all", "--only", "codec,nope").returncode == 2
    assert sil("bench", "codec", "--markdown", "x.md").returncode == 2
    missing = sil("bench", "all", "--only", "codec", "--markdown", "/no/such/dir/b.md")
    assert missing.returncode == 2 and "no such folder" in missing.stderr
