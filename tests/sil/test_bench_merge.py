"""`sil bench all --only X --merge --markdown PAGE`: the benches run now are written into the
page, replacing theirs, and every other bench's rows and section stay byte for byte."""

from __future__ import annotations

from sil.bench.suite import markdown, merge

MACHINE = {"cpu": "Test CPU", "cores": 2, "load_average_1min": 0.5, "python": "3.11",
           "os": "Linux", "load_average_1min_after": 0.6}  # fmt: skip


def _result(date: str, **benches: dict) -> dict:
    entries = {
        name: {"what": f"the {name} bench", "figures": figures, "seconds": 1.0,
               "targets_met": {"targets": figures["targets_met"]},
               "target_text": {"targets": f"{name} target"}}
        for name, figures in benches.items()
    }  # fmt: skip
    return {"date": date, "mode": "full", "machine": MACHINE, "benches": entries}


def test_a_merge_replaces_the_benches_run_and_keeps_the_others() -> None:
    page = markdown(_result("2026-12-01 10:00 UTC", codec={"speed": 1.5, "targets_met": True},
                            fleet={"engines": 500, "targets_met": False}))  # fmt: skip
    fresh = _result("2026-12-07 04:00 UTC", fleet={"engines": 501, "targets_met": True},
                    gsu={"updates_per_s": 20.0, "targets_met": True})  # fmt: skip
    merged = merge(page, fresh)
    codec_section = page[page.index("## `sil bench codec`") : page.index("## `sil bench fleet`")]
    assert codec_section in merged
    assert "| codec | codec target | yes |" in merged
    assert "| fleet | fleet target | yes |" in merged and "**no**" not in merged
    assert "| `engines` | 501 |" in merged and "| `engines` | 500 |" not in merged
    assert merged.index("## `sil bench codec`") < merged.index("## `sil bench fleet`") < \
        merged.index("## `sil bench gsu`")  # fmt: skip
    assert "`fleet`, `gsu` (full runs, 2026-12-07 04:00 UTC, Test CPU" in merged
    assert merged.startswith(page[: page.index("## Targets")].rstrip("\n"))
    again = merge(merged, _result("2026-12-08 04:00 UTC", gsu={"updates_per_s": 21.0,
                                                               "targets_met": True}))  # fmt: skip
    assert again.count("## `sil bench gsu`") == 1 and "| `updates_per_s` | 21 |" in again
    assert codec_section in again
