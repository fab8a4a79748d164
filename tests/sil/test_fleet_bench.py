"""`sil bench fleet`: the campaign figures read from results rows whose answer is known, and the
quick bench against what physics and the document say."""

from __future__ import annotations

import json
import subprocess
import sys

from sil.bench import fleet as fleet_bench


def _row(kind: str, variant: str, sample: int, rise: float, violations: str = "", **kw) -> dict:
    row = {
        "status": "completed", "sample": str(sample), "controller.kind": kind, "variant": variant,
        "step_pct": "45.0" if variant == "accel" else "-45.0", "thrust_rise_s": str(rise),
        "egt_overshoot_K": "0.0", "min_surge_margin_pct": "15.0", "flameouts": "0",
        "min_speed_pct": "55.0", "tracking_rms_pct": "1.0", "tracking_mean_pct": "0.0",
        "protection_time_s": "0.0", "violations": violations,
    }  # fmt: skip
    row.update({k: str(v) for k, v in kw.items()})
    return row


def test_transient_figures_count_the_rises_and_split_the_violations() -> None:
    rows = [
        _row("mrac", "accel", -1, 4.8),
        _row("mrac", "accel", 0, 5.0),
        _row("mrac", "accel", 1, 6.2, "thrust_rise: 6.20 s > 5 s"),
        _row("mrac", "chop", -1, 2.3),
        _row(
            "mrac",
            "chop",
            0,
            3.1,
            "egt: 1295.0 K > 1290 K (peak at 1.20 s)",
            egt_overshoot_K=15.0,
            min_speed_pct=49.0,
        ),  # fmt: skip
    ]
    got = fleet_bench._transients(rows)
    assert got["transient_mrac_accel_within_5_s"] == 2
    assert got["transient_mrac_accel_engines"] == 3
    assert got["transient_mrac_accel_rise_nominal_s"] == 4.8
    assert got["transient_mrac_accel_rise_max_s"] == 6.2
    assert got["transient_mrac_chop_fall_nominal_s"] == 2.3
    assert got["transient_mrac_chop_egt_overshoot_max_K"] == 15.0
    assert got["transient_mrac_chop_speed_min_pct"] == 49.0
    assert got["transient_limit_violations"] == 1
    assert got["transient_rise_violations"] == 1


def test_variation_figures_split_the_held_engines() -> None:
    rows = [_row("mrac", "", -1, 0.0, tracking_rms_pct=0.15)]
    rows += [_row("mrac", "", k, 0.0, tracking_rms_pct=0.2 + 0.01 * k) for k in range(19)]
    rows.append(_row("mrac", "", 19, 0.0, "egt: 1310.0 K > 1305 K", tracking_rms_pct=5.0,
                     protection_time_s=12.0))  # fmt: skip
    got = fleet_bench._variation(rows)
    assert got["variation_runs"] == 21 and got["variation_runs_with_violations"] == 1
    assert got["variation_mrac_rms_nominal_pct"] == 0.15
    assert got["variation_mrac_held_engines"] == 1
    assert got["variation_mrac_rms_p95_free_pct"] < 0.4 < got["variation_mrac_rms_p95_pct"]
    # time on limiters: the held engine's 12 s over the 20 varied engines, the nominal's none
    assert got["variation_mrac_limiter_time_nominal_s"] == 0.0
    assert got["variation_mrac_limiter_time_median_s"] == 0.0
    assert got["variation_mrac_limiter_time_mean_s"] == 0.6


def test_the_quick_bench_no_engine_beats_its_physics_and_the_mrac_tracks_closest() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "sil.cli", "bench", "fleet", "--quick", "--json"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    f = json.loads(done.stdout)
    assert f["variation_runs"] == 3 * fleet_bench.QUICK_ENGINES
    assert f["transient_runs"] == 6 * fleet_bench.QUICK_ENGINES
    # the nominal engine on its own acceleration line, at frozen speed, is the fastest any
    # controller could make it: no controller beats it
    bound = f["rise_bound_nominal_own_line_s"]
    assert 3.0 < bound < 6.0
    for kind in fleet_bench.CONTROLLERS:
        assert f[f"transient_{kind}_accel_rise_nominal_s"] >= bound
        assert f[f"transient_{kind}_chop_flameout_runs"] == 0
    # the document's claims: the MRAC tracks closer, also when the pump fails (sec. 6.3)
    assert f["failure_mrac_tracking_rms_pct"] < 0.5 * f["failure_pid_tracking_rms_pct"]
    assert f["variation_mrac_rms_median_pct"] < 0.5 * f["variation_pi_rms_median_pct"]
    assert set(f["targets_met"]) == set(fleet_bench.TARGET_TEXT)
    assert f["targets_met"]["variation"] and f["targets_met"]["transient_limits"]
