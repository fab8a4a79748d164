"""The limit loops' min-select does not turn sensor noise into a bias of the command: a loop that
does not own the command joins on its integral part alone (ecu.limiters)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ecu.limiters import OWNER_EGT, OWNER_SPEED


def _held_speed(make_rig: Any, limiters: bool, seed: int) -> tuple[float, float]:
    """Mean speed and the EGT loop's share of the ticks over 5 s at constant demand, the probe
    reading 2 K of noise with the steady EGT 30 K under the limit (inside the 50 K band)."""
    params = replace(make_rig().params, egt_engage_k=50.0, limiters_on=limiters)
    rig = make_rig(params=params, hot_k=1280.0 - 30.0 - 1048.0)  # 1250 K at the trim speed
    noise = np.random.default_rng(seed).normal(0.0, 2.0, 1200)
    speeds, owners = [], []
    for k in range(1200):
        rig.step(1, egt_dk=round((rig.egt_k + noise[k]) * 10.0))
        if k >= 700:
            speeds.append(rig.plant.n_pct)
            owners.append(rig.out.owner)
    return float(np.mean(speeds)), float(np.mean(np.array(owners) == OWNER_EGT))


def test_an_egt_loop_inside_its_band_does_not_pull_the_speed_down(make_rig: Any) -> None:
    trim = make_rig().params.trim_n_pct
    banded, share = _held_speed(make_rig, True, seed=1)
    free, _ = _held_speed(make_rig, False, seed=1)  # the speed loop alone
    assert abs(free - trim) < 0.05
    assert abs(banded - free) < 0.05
    # 30 K from its limit the loop owns almost no tick (with its P part on the lead's noise in
    # every candidate the min-select gave it 75 % of them, each a downward kick)
    assert share < 0.05


def test_the_loop_that_owns_keeps_its_p_part(make_rig: Any) -> None:
    """Stepped into its limit the EGT loop owns and holds the engine there, its P part acting."""
    rig = make_rig(hot_k=150.0)
    rig.step(300)
    assert rig.out.owner == OWNER_SPEED
    rig.step(800, demand_cpct=9500)
    assert rig.out.owner == OWNER_EGT
    assert abs(rig.egt_steady() - 1280.0) < 5.0
