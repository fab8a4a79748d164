"""The report's tracking figures from a results table: percentiles against numpy's, and the
split of the engines a protection held off the demand."""

import numpy as np

from sil.campaign.report import _targets, tracking


def row(sample: int, kind: str, rms: float, protection_s: float) -> dict:
    return {
        "status": "completed",
        "sample": str(sample),
        "controller.kind": kind,
        "tracking_rms_pct": repr(rms),
        "tracking_mean_pct": "0.0",
        "protection_time_s": repr(protection_s),
    }


def test_engines_held_by_a_protection_are_counted_and_left_out_of_the_free_percentile():
    rng = np.random.default_rng(3)
    free = rng.uniform(0.1, 0.2, 40)
    held = rng.uniform(1.0, 3.0, 10)
    rows = [row(-1, "mrac", 0.1, 0.0)]
    rows += [row(i, "mrac", float(x), 0.3) for i, x in enumerate(free)]  # a brush at a step
    rows += [row(40 + i, "mrac", float(x), 5.0) for i, x in enumerate(held)]
    rows += [row(i, "pid", 2.0, 0.0) for i in range(50)]
    t = tracking(rows)["mrac"]
    assert t["runs"] == 50 and t["limited"] == 10
    assert t["p95"] == np.percentile(np.concatenate([free, held]), 95)
    assert t["p95_free"] == np.percentile(free, 95)
    # time on limiters over the varied engines: 40 brushes of 0.3 s and 10 holds of 5 s
    assert t["limiter_s_nominal"] == 0.0 and t["limiter_s_p50"] == 0.3
    assert abs(t["limiter_s_mean"] - (40 * 0.3 + 10 * 5.0) / 50) < 1e-12
    text = "\n".join(_targets(tracking(rows)))
    assert "NOT met" in text and "On 10 of the 50 engines a protection" in text
    assert f"{np.percentile(free, 95) / 0.1:.2f}x" in text
    assert "target (MRAC better) met" in text
