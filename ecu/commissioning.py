"""Commissioning: the trim point and initial estimates of an engine, from a bench log.

``sil identify --export FILE`` writes them (eq. 3.22 on the engine's own data); the ECU reads the
file at start-up. The MRAC's initial gains follow from the estimates by the matching conditions
(eq. 5.9): K_x = -(A_p row 2 - A_m row 2) / Lambda, K_r = omega_m^2 / Lambda and
K_f = -Theta_f / Lambda.
This is configuration-time code (floats), not part of the firmware tick.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

from ecu.firmware_params import compile_params
from ecu.params import EcuParams, ParamError

FORMAT = "turbojet-sil commissioning 1"


def _number(data: dict, key: str, path: Path) -> float:
    value = data.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ParamError(f"{path}: field '{key}' must be a finite number, got {value!r}")
    return float(value)


def _pair(data: dict, key: str, path: Path) -> tuple[float, float]:
    value = data.get(key)
    if not isinstance(value, list) or len(value) != 2:
        raise ParamError(f"{path}: field '{key}' must be a list of two numbers, got {value!r}")
    return _number({"0": value[0]}, "0", path), _number({"1": value[1]}, "1", path)


def load(path: Path) -> dict:
    """The commissioning file, checked field by field."""
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ParamError(f"{path}: cannot read the commissioning file: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ParamError(f"{path}: not a commissioning file (expected format '{FORMAT}')")
    checked = {
        "trim_N_pct": _number(data, "trim_N_pct", path),
        "trim_V": _number(data, "trim_V", path),
        "Ap_row2": _pair(data, "Ap_row2", path),
        "Lambda": _number(data, "Lambda", path),
        "Theta_row2": _pair(data, "Theta_row2", path),
    }
    if checked["Lambda"] <= 0:
        raise ParamError(
            f"{path}: field 'Lambda' must be positive (pump gain), got {checked['Lambda']}"
        )
    return checked


def commission(params: EcuParams, path: Path) -> EcuParams:
    """``params`` commissioned from the file at ``path``, checked as the ECU checks it on
    load; a refusal names the file."""
    commissioned = apply(params, load(path))
    try:
        compile_params(commissioned)
    except ParamError as exc:
        raise ParamError(f"{path}: the ECU refuses this commissioning: {exc}") from None
    return commissioned


def apply(params: EcuParams, data: dict) -> EcuParams:
    """``params`` with the commissioned trim point, initial estimates and matching gains."""
    lam = data["Lambda"]
    am21, am22 = -(params.ref_wn**2), -2.0 * params.ref_zeta * params.ref_wn  # eq. 5.18
    ap21, ap22 = data["Ap_row2"]
    th1, th2 = data["Theta_row2"]
    return replace(
        params,
        trim_n_pct=data["trim_N_pct"],
        trim_v=data["trim_V"],
        init_ap_row2=(ap21, ap22),
        init_lambda=lam,
        init_theta_row2=(th1, th2),
        lambda_commissioned=lam,
        init_kx=(-(ap21 - am21) / lam, -(ap22 - am22) / lam),  # eq. 5.9
        init_kr=params.ref_wn**2 / lam,
        init_kf=(-th1 / lam, -th2 / lam),
    )
