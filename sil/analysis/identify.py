"""Offline identification of the fast engine model from a recording (ch. 3, appendix B).

Second-order model (eq. 3.8, 3.11), in deviations from a trim point (N in %N_max, V in volts):

    dN'' = theta0 dN + theta1 dN' + theta2 dV + theta3 dN dV + theta4 dN^2 dV
    theta = [-wn^2, -2 zeta wn, a0 wn^2, a1 wn^2, a2 wn^2]

First-order models of appendix B (eq. B.4, and B.4 with a dN^2 dV term as in eq. B.17):

    dN' = theta0 dN + theta1 dV + theta2 dN dV [+ theta3 dN^2 dV],  theta0 = -1/tau

Speed rate and acceleration come from local polynomial least squares (Savitzky-Golay, the
document's sec. 3.4), which also copes with noisy data logged at 10 Hz. theta is the least-squares
solution of eq. 3.22; the fit is judged by simulating the identified model with the recorded
voltage and comparing its speed with the recorded one (NRMSE, in percent of the speed range).
"""

from __future__ import annotations

import math
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

from protocol import strict_json

# eq. 3.5; eq. 3.1 (linear second order); eq. B.4; appendix B linear; B.4 + dN^2 dV
ORDERS = ("second", "second-linear", "first", "first-linear", "first-quadratic")
SECOND_ORDERS = ("second", "second-linear")
MAX_NRMSE_PCT = 10.0  # a fit further than this from the data it is judged on is not trusted
# the ECU parameter a commissioning file sets -> the file's field
_EXPORT_FIELDS = {
    "trim_n_pct": "trim_N_pct",
    "trim_v": "trim_V",
    "init_ap_row2": "Ap_row2",
    "init_lambda": "Lambda",
    "lambda_commissioned": "Lambda",
    "init_theta_row2": "Theta_row2",
    "init_kx": "Ap_row2",  # eq. 5.9: the gains follow from the estimates
    "init_kr": "Lambda",
    "init_kf": "Theta_row2",
}


@dataclass(frozen=True)
class Recording:
    """Uniformly sampled time (s), speed (%N_max) and pump voltage (V)."""

    t: np.ndarray
    n_pct: np.ndarray
    v: np.ndarray
    source: str

    @property
    def dt(self) -> float:
        return float(np.median(np.diff(self.t)))

    def part(self, start: float, end: float) -> Recording:
        """The samples with start <= fraction of the record < end."""
        i0, i1 = int(start * len(self.t)), int(end * len(self.t))
        return Recording(self.t[i0:i1], self.n_pct[i0:i1], self.v[i0:i1], self.source)


@dataclass(frozen=True)
class Trim:
    n_pct: float
    v: float


@dataclass(frozen=True)
class Derivatives:
    n: np.ndarray  # smoothed speed
    n_dot: np.ndarray
    n_ddot: np.ndarray
    window: int  # samples


def auto_window(rec: Recording, seconds: float = 0.5) -> int:
    """An odd window of about ``seconds`` (at least 7 samples): the smoothing of sec. 3.4."""
    w = max(7, int(round(seconds / rec.dt)))
    return w if w % 2 else w + 1


def derivatives(rec: Recording, window: int | None = None, order: int = 3) -> Derivatives:
    """Smoothed speed and its first two derivatives by local polynomial least squares."""
    w = window or auto_window(rec)
    if w % 2 == 0 or w <= order:
        raise ValueError(f"smoothing window {w} must be odd and longer than the order {order}")
    if w > len(rec.t):
        raise ValueError(f"smoothing window {w} is longer than the record ({len(rec.t)} samples)")
    dt = rec.dt
    return Derivatives(
        savgol_filter(rec.n_pct, w, order, mode="interp"),
        savgol_filter(rec.n_pct, w, order, deriv=1, delta=dt, mode="interp"),
        savgol_filter(rec.n_pct, w, order, deriv=2, delta=dt, mode="interp"),
        w,
    )


def smooth_input(v: np.ndarray, window: int, tolerance: float = 1e-3) -> np.ndarray:
    """Samples whose smoothing window holds no step of the input.

    The acceleration jumps with a voltage step (the a0 wn^2 dV term), and a polynomial fitted
    across the jump smears it: those samples would bias theta, so least squares leaves them out.
    """
    half = window // 2
    step = np.abs(np.diff(v)) > tolerance * max(1.0, float(np.ptp(v)))
    edges = np.concatenate(([0], np.cumsum(step)))  # number of steps up to each sample
    lo = np.clip(np.arange(len(v)) - half, 0, len(v) - 1)
    hi = np.clip(np.arange(len(v)) + half, 0, len(v) - 1)
    return edges[hi] == edges[lo]


def estimate_trim(rec: Recording, seconds: float = 1.0) -> Trim:
    """The trim point as the mean of the first ``seconds`` (records start in a steady state)."""
    k = max(1, int(seconds / rec.dt))
    return Trim(float(np.mean(rec.n_pct[:k])), float(np.mean(rec.v[:k])))


def regressors(dn: np.ndarray, dn_dot: np.ndarray, dv: np.ndarray, order: str) -> np.ndarray:
    """The regressor matrix X of eq. 3.14 (or of eq. B.7 for the first-order models)."""
    if order == "second":
        return np.column_stack([dn, dn_dot, dv, dn * dv, dn * dn * dv])
    if order == "second-linear":
        return np.column_stack([dn, dn_dot, dv])
    if order == "first-linear":
        return np.column_stack([dn, dv])
    if order == "first":
        return np.column_stack([dn, dv, dn * dv])
    if order == "first-quadratic":
        return np.column_stack([dn, dv, dn * dv, dn * dn * dv])
    raise ValueError(f"model order '{order}' is not one of {', '.join(ORDERS)}")


def least_squares(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """theta-hat = (X^T X)^-1 X^T Y (eq. 3.22), solved stably."""
    theta, *_ = np.linalg.lstsq(x, y, rcond=None)
    return theta


def simulate(
    theta: np.ndarray, order: str, rec: Recording, trim: Trim, substeps: int = 4
) -> np.ndarray:
    """Speed (%N) of the identified model driven by the recorded voltage (RK4, input held)."""
    th = [float(v) for v in theta] + [0.0] * (5 - len(theta))
    second = order in SECOND_ORDERS
    if order not in ORDERS:
        raise ValueError(f"model order '{order}' is not one of {', '.join(ORDERS)}")

    def rate(dn: float, dn_dot: float, u: float) -> tuple[float, float]:
        if second:  # eq. 3.4
            gain = th[2] + th[3] * dn + th[4] * dn * dn
            return dn_dot, th[0] * dn + th[1] * dn_dot + gain * u
        gain = th[1] + th[2] * dn + th[3] * dn * dn  # eq. B.4 (+ dN^2 dV)
        return th[0] * dn + gain * u, 0.0

    h = rec.dt / substeps
    dn, dn_dot = float(rec.n_pct[0] - trim.n_pct), 0.0
    out = np.full(len(rec.t), math.nan)
    for k, u in enumerate((rec.v - trim.v).tolist()):
        out[k] = dn
        for _ in range(substeps):
            a1, b1 = rate(dn, dn_dot, u)
            a2, b2 = rate(dn + 0.5 * h * a1, dn_dot + 0.5 * h * b1, u)
            a3, b3 = rate(dn + 0.5 * h * a2, dn_dot + 0.5 * h * b2, u)
            a4, b4 = rate(dn + h * a3, dn_dot + h * b3, u)
            dn += h / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4)
            dn_dot += h / 6.0 * (b1 + 2 * b2 + 2 * b3 + b4)
        if not math.isfinite(dn) or abs(dn) > 1e3:
            out[k:] = math.nan  # the identified model is unstable on this input
            break
    return out + trim.n_pct


def nrmse_pct(simulated: np.ndarray, measured: np.ndarray) -> float:
    """RMS error in percent of the measured range (inf when the simulation diverged)."""
    if not np.all(np.isfinite(simulated)):
        return math.inf
    span = float(np.ptp(measured)) or 1.0
    return 100.0 * float(np.sqrt(np.mean((simulated - measured) ** 2))) / span


@dataclass
class Identification:
    order: str
    theta: list[float]
    trim: Trim
    window: int
    derived: dict[str, float | list[str]]
    skip_steps: bool = True
    nrmse_pct: float | None = None

    def as_dict(self) -> dict:
        return {
            "order": self.order,
            "theta": self.theta,
            "trim": {"N_pct": self.trim.n_pct, "V": self.trim.v},
            "smoothing_window_samples": self.window,
            "steps_skipped": self.skip_steps,
            **self.derived,
            "nrmse_pct": self.nrmse_pct,
        }


def derived_parameters(theta: np.ndarray, order: str) -> dict[str, float | list[str]]:
    """omega_n, zeta, alpha_i and the roots (ch. 3); tau and alpha_i (appendix B)."""
    if order in SECOND_ORDERS:
        wn = math.sqrt(-theta[0]) if theta[0] < 0 else math.nan
        roots = np.roots([1.0, -theta[1], -theta[0]])
        out = {
            "omega_n": wn,
            "zeta": -theta[1] / (2 * wn) if wn else math.nan,
            "alpha0": theta[2] / wn**2,
        }
        if order == "second-linear":
            return {**out, "K": out["alpha0"], "roots": [f"{r:.4f}" for r in roots]}
        return {
            **out,
            "alpha1": theta[3] / wn**2,
            "alpha2": theta[4] / wn**2,
            "roots": [f"{r:.4f}" for r in roots],
        }
    tau = -1.0 / theta[0] if theta[0] != 0 else math.inf
    out = {"tau": tau, "K": theta[1] * tau, "alpha0": theta[1] * tau}
    if order == "first-linear":
        return out
    out["alpha1"] = theta[2] * tau
    if order == "first-quadratic":
        out["alpha2"] = theta[3] * tau
    return out


def candidate_windows(rec: Recording) -> list[int]:
    """Odd smoothing windows from 7 samples (or 0.05 s) up to about 2 s."""
    lo = max(7, int(0.05 / rec.dt) | 1)
    hi = max(lo, min(int(2.0 / rec.dt) | 1, (len(rec.t) // 4) | 1))
    return sorted({int(w) | 1 for w in np.geomspace(lo, hi, 8)})


def identify(
    rec: Recording,
    *,
    order: str = "second",
    trim: Trim | None = None,
    window: int | None = None,
    skip_steps: bool | None = None,
) -> Identification:
    """Least squares of the chosen model on a recording (deviations from ``trim``).

    ``skip_steps`` leaves out the samples whose smoothing window holds a voltage step (see
    :func:`smooth_input`): right for densely sampled data, where the rest still holds the
    transients, wrong for slow logs, where mostly steady states would be left. Without a window
    (or with ``skip_steps`` None), every candidate window (:func:`candidate_windows`), with and
    without skipping, is tried and the model that, simulated on the recording, fits it best is
    kept.
    """
    if len(rec.t) < 20:
        raise ValueError(f"{rec.source}: {len(rec.t)} samples are too few to identify a model")
    trim = trim or estimate_trim(rec)
    _check_trim(rec, trim)
    if window is None or skip_steps is None:
        tried = []
        for w in candidate_windows(rec) if window is None else [window]:
            for skip in (True, False) if skip_steps is None else (skip_steps,):
                try:
                    ident = identify(rec, order=order, trim=trim, window=w, skip_steps=skip)
                except ValueError:
                    continue
                tried.append((validate(ident, rec), w, not skip, ident))
        if not tried:
            raise ValueError(f"{rec.source}: no smoothing window fits this record")
        fit, *_, best = min(tried, key=lambda item: item[:3])
        best.nrmse_pct = fit
        return best
    d = derivatives(rec, window)
    dn, dv = d.n - trim.n_pct, rec.v - trim.v
    x = regressors(dn, d.n_dot, dv, order)
    y = d.n_ddot if order in SECOND_ORDERS else d.n_dot
    keep = smooth_input(rec.v, d.window) if skip_steps else np.ones(len(y), bool)
    if keep.sum() < x.shape[1] * 5:
        raise ValueError(
            f"{rec.source}: the voltage changes too often for the smoothing window "
            f"({d.window} samples); give a shorter --window"
        )
    if not (np.all(np.isfinite(x[keep])) and np.all(np.isfinite(y[keep]))):
        raise ValueError(f"{rec.source}: the regressors are not finite with this trim point")
    theta = least_squares(x[keep], y[keep])
    return Identification(
        order,
        [float(v) for v in theta],
        trim,
        d.window,
        derived_parameters(theta, order),
        skip_steps,
    )


def _check_trim(rec: Recording, trim: Trim) -> None:
    """Refuse a trim point so far from the data that the model's terms (up to dN^2 dV) are not
    finite numbers (least squares would then fail in LAPACK)."""
    with np.errstate(over="ignore", invalid="ignore"):
        dn, dv = rec.n_pct - trim.n_pct, rec.v - trim.v
        finite = np.all(np.isfinite(dn * dn * dv)) and np.all(np.isfinite(dn * dn))
    if not (math.isfinite(trim.n_pct) and math.isfinite(trim.v) and finite):
        raise ValueError(
            f"{rec.source}: the trim point ({trim.n_pct:g} %N, {trim.v:g} V) is too far from "
            "the recorded speed and voltage to fit a model around it"
        )


def validate(ident: Identification, rec: Recording) -> float:
    """NRMSE of the identified model simulated on ``rec`` (held-out data or another file)."""
    simulated = simulate(np.asarray(ident.theta), ident.order, rec, ident.trim)
    return nrmse_pct(simulated, rec.n_pct)


def ecu_commissioning(ident: Identification) -> dict:
    """The initial estimates and trim point for the ECU (eq. 4.2-4.5 from theta)."""
    if ident.order != "second":
        raise ValueError("the ECU's estimator uses the second-order model: identify with it")
    th = ident.theta
    return {
        "format": "turbojet-sil commissioning 1",
        "trim_N_pct": ident.trim.n_pct,
        "trim_V": ident.trim.v,
        "Ap_row2": th[0:2],
        "Lambda": th[2],
        "Theta_row2": th[3:5],
    }


def write_json(path: Path, data: dict) -> None:
    path.write_text(strict_json.dumps(data, indent=2) + "\n")


def commissioning_refusal(data: dict) -> str | None:
    """Why the ECU would refuse this commissioning file (None: it loads it): the file written and
    read back, applied to the ECU's default parameters and compiled, as `sil ecu --commission`
    does; the reason names the file's field."""
    from ecu import commissioning
    from ecu.firmware_params import compile_params
    from ecu.params import ParamError, preset

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "commissioning.json"
        write_json(path, data)
        try:
            compile_params(commissioning.apply(preset("default"), commissioning.load(path)))
        except ParamError as exc:
            reason = str(exc).replace(f"{path}: ", "")
        else:
            return None
    named = re.match(r"(\w+)=", reason)
    field = _EXPORT_FIELDS.get(named.group(1)) if named else None
    return f"field '{field}': {reason}" if field else reason


def running_range() -> tuple[float, float]:
    """The speeds (%N) the fast model describes: where the ECU's speed control flies the engine,
    from where its start hands the engine over (start_idle_pct) to its overspeed limit
    (overspeed_pct), with the ECU's default parameters."""
    from ecu.params import preset

    params = preset("default")
    return params.start_idle_pct, params.overspeed_pct


def distrust(ident: Identification, recordings: list[Recording]) -> list[str]:
    """Why the fit is not to be trusted (an empty list: it is): a fit error above
    ``MAX_NRMSE_PCT`` on the data it is judged on, a trim point or samples outside the
    running range (:func:`running_range`)."""
    reasons = []
    error = ident.nrmse_pct
    if error is None or not error <= MAX_NRMSE_PCT:
        shown = "diverging" if error is None or not math.isfinite(error) else f"{error:.1f} %"
        reasons.append(f"fit error (NRMSE) {shown}, above {MAX_NRMSE_PCT:g} %")
    lo, hi = running_range()
    if not lo <= ident.trim.n_pct <= hi:
        reasons.append(
            f"trim point {ident.trim.n_pct:.4g} %N outside the running range {lo:g}..{hi:g} %N"
        )
    for rec in recordings:
        outside = int(np.count_nonzero((rec.n_pct < lo) | (rec.n_pct > hi)))
        if outside:
            reasons.append(
                f"{rec.source}: {outside} of {len(rec.n_pct)} samples outside the running range "
                f"{lo:g}..{hi:g} %N (they span {np.min(rec.n_pct):.1f}..{np.max(rec.n_pct):.1f} %N)"
            )
    return reasons


N_MAX_RPM = 112_500.0


def _uniform(t: np.ndarray, n: np.ndarray, v: np.ndarray, source: str) -> Recording:
    """Sort, drop repeated times and resample onto a uniform grid at the median step."""
    if len(t) < 20:
        raise ValueError(f"{source}: only {len(t)} usable samples of time, speed and voltage")
    order = np.argsort(t, kind="stable")
    t, n, v = t[order], n[order], v[order]
    keep = np.concatenate(([True], np.diff(t) > 0))
    t, n, v = t[keep], n[keep], v[keep]
    finite = np.isfinite(t) & np.isfinite(n) & np.isfinite(v)
    if not finite.all():
        first = float(t[~finite][0])
        raise ValueError(
            f"{source}: {int((~finite).sum())} samples hold NaN or inf (first at time {first:g}); "
            "a model cannot be identified from them"
        )
    if len(t) < 20:
        raise ValueError(f"{source}: only {len(t)} usable samples of time, speed and voltage")
    for name, x in (("voltage (the input)", v), ("speed (the output)", n)):
        if float(np.ptp(x)) == 0.0:
            raise ValueError(
                f"{source}: the {name} is constant ({x[0]:g}): no excitation to identify from"
            )
    dt = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1] + 0.5 * dt, dt)
    # a zero-order hold for the voltage (a command), linear for the speed (a measurement)
    index = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 1)
    return Recording(grid - grid[0], np.interp(grid, t, n), v[index], source)


def read_csv(
    path: Path, time_column: str, speed_column: str, voltage_column: str, speed_unit: str = "pct"
) -> Recording:
    """A CSV with a header row; ``name[unit]`` headers (our trace.csv) match by name too."""
    import csv

    with path.open(newline="") as f:
        reader = csv.reader(f)
        try:
            header = next(reader)
        except StopIteration:
            raise ValueError(f"{path}: empty file") from None
        names = [h.split("[", 1)[0].strip() for h in header]
        columns = []
        for wanted in (time_column, speed_column, voltage_column):
            if wanted in header:
                columns.append(header.index(wanted))
            elif wanted in names:
                columns.append(names.index(wanted))
            else:
                raise ValueError(f"{path}: no column '{wanted}' (columns: {', '.join(names)})")
        rows = []
        for row in reader:
            if not row:
                continue
            try:
                values = [float(row[i]) for i in columns]
            except (ValueError, IndexError):
                raise ValueError(
                    f"{path}, line {reader.line_num}: expected numbers in columns "
                    f"{time_column}, {speed_column}, {voltage_column}"
                ) from None
            if rows and not values[0] > rows[-1][0]:  # also NaN
                raise ValueError(
                    f"{path}, line {reader.line_num}: time {row[columns[0]]} does not follow "
                    f"{rows[-1][0]:g}: a recording's time must increase"
                )
            rows.append(values)
    data = np.asarray(rows, dtype=float).reshape(-1, 3)
    speed = data[:, 1] * (100.0 / N_MAX_RPM if speed_unit == "rpm" else 1.0)
    return _uniform(data[:, 0], speed, data[:, 2], str(path))


def read_can_log(path: Path) -> Recording:
    """Speed (PlantSensors) and pump voltage (EcuActuator) from a CAN log with our DBC."""
    from protocol.codec import Codec
    from sil.record.canlog import LogReadError, read_frames
    from sil.record.replay import wrong_length

    codec = Codec()
    sensors, actuator = codec["PlantSensors"], codec["EcuActuator"]
    i_speed = sensors.signal_names.index("ShaftSpeed")
    i_volt = actuator.signal_names.index("PumpVoltageTarget")
    out = [0.0] * 8
    speed = math.nan
    t, n, v = [], [], []
    reader = read_frames(path)
    for msg in reader:
        if msg.is_extended_id or msg.is_fd or msg.is_error_frame or msg.is_remote_frame:
            continue
        ours = codec.by_id.get(msg.arbitration_id)
        if ours in (sensors, actuator) and len(msg.data) != ours.length:
            reason = wrong_length(ours, len(msg.data))
            raise LogReadError(path, reader.position, reason, reader.frames - 1)
        if msg.arbitration_id == sensors.frame_id:
            sensors.unpack(msg.data, out)
            speed = out[i_speed] * 100.0 / N_MAX_RPM
        elif msg.arbitration_id == actuator.frame_id and math.isfinite(speed):
            actuator.unpack(msg.data, out)
            t.append(msg.timestamp)
            n.append(speed)
            v.append(out[i_volt])
    return _uniform(np.asarray(t), np.asarray(n), np.asarray(v), str(path))


def read_recording(
    path: Path,
    *,
    time_column: str = "time",
    speed_column: str = "speed_meas",
    voltage_column: str = "PumpVoltageTarget",
    speed_unit: str = "pct",
) -> Recording:
    """A trace.csv of ``sil run``, a CAN log with our DBC, or a plain CSV (columns by name)."""
    from sil.record.canlog import LogReadError, detect_format

    try:
        fmt, _ = detect_format(path)
    except LogReadError:
        fmt = "other"
    if fmt in ("candump", "asc", "blf", "trc", "csv", "mf4"):  # csv: python-can's CSV log
        return read_can_log(path)
    return read_csv(path, time_column, speed_column, voltage_column, speed_unit)
