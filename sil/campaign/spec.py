"""Campaign files (TOML): a base scenario and what to vary, expanded into cases.

    name = "engine-variation"
    description = "..."
    base = "thesis-5.4-staircase"  # a shipped scenario, or a file relative to this one
    duration_s = 60                # optional: replaces the base's duration
    seed = 1                       # draws of [sample] and the noise seed of each sample
    samples = 500                  # random engines drawn from [sample]
    nominal = true                 # also the base engine itself (once per sweep combination)

    [sample]                       # scenario field (dotted path) -> distribution
    "plant.compressor_efficiency" = { uniform = [0.95, 1.05] }
    "plant.ambient_temperature_K" = { normal = [288.15, 5.0] }
    "plant.pump_gain" = { choice = [0.8, 1.0, 1.2] }

    [sweep]                        # every combination of these, for each sample
    "controller.kind" = ["mrac", "pid"]

    [[variant]]                    # one more axis: named overlays on the base scenario
    name = "sensor-bit-flips"
    [[variant.bus_fault]]
    kind = "bitflip"
    ...

    [invariants]                   # see sil.campaign.invariants
    max_speed_pct = 102.0
    egt_margin_K = 25.0
    min_surge_margin_pct = 0.0
    check_flameout = true
    check_undershoot = false
    max_thrust_rise_s = 5.0        # default: not checked

Cases come samples outermost (the same engine and noise seed under every sweep combination and
variant, so controllers are compared on equal engines). Each case is a complete scenario; every
one is checked before anything runs, and a bad one is refused naming the campaign file, the
case and the field.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sil import scenario as scenarios
from sil.campaign.tomlw import dumps

DISTRIBUTIONS = ("uniform", "normal", "choice")
MAX_CASES = 100_000  # every case is built and checked before the first runs


class CampaignError(ValueError):
    """A campaign file that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class Invariants:
    max_speed_pct: float = 102.0  # true speed never above (the topping governor's limit)
    egt_margin_K: float = 25.0  # true EGT never above the ECU's EGT limit by more than this
    min_surge_margin_pct: float = 0.0  # the compressor's surge margin never under this (true P3)
    check_flameout: bool = True  # no flameout while the ECU is in RUN
    check_undershoot: bool = False  # in RUN, true speed never under the ECU's flameout threshold
    max_thrust_rise_s: float = math.inf  # the largest demand step: 95 % of its thrust within this
    check_faults: bool = True  # each [[bus_fault]] expectation (detect, fallback, recovery)
    # a start from rest: RUN reached, no hot start (true EGT over the ECU's start limit plus
    # egt_margin_K), no hung start, every abort with its reason
    check_start: bool = False
    max_cool_down_s: float = math.inf  # the true EGT under 373 K within this of the fuel cut


@dataclass(frozen=True)
class Case:
    run_id: str
    sample: int  # -1: the nominal engine
    values: dict[str, Any]  # axis -> value (dotted paths, "variant")
    scenario_toml: str  # the complete scenario
    digest: str  # of scenario_toml: a resumed campaign reruns a case whose content changed


@dataclass(frozen=True)
class Campaign:
    name: str
    description: str
    path: Path
    axes: tuple[str, ...]  # columns of the results table, in order
    cases: tuple[Case, ...]
    invariants: Invariants


def _fail(source: str, field: str, expected: str, got: Any) -> CampaignError:
    return CampaignError(f"{source}: field '{field}': expected {expected}, got {got!r}")


def _number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _non_finite(data: Any, field: str = "") -> tuple[str, float] | None:
    """The first NaN or infinite number in a TOML value, with its field, or None."""
    if isinstance(data, float) and not math.isfinite(data):
        return field, data
    items: Any = ()
    if isinstance(data, dict):
        items = ((f"{field}.{k}" if field else str(k), v) for k, v in data.items())
    elif isinstance(data, list):
        items = ((f"{field}[{i}]", v) for i, v in enumerate(data))
    for where, value in items:
        found = _non_finite(value, where)
        if found is not None:
            return found
    return None


def _distribution(source: str, key: str, spec: Any) -> tuple[str, list]:
    field = f"sample.{key}"
    if not isinstance(spec, dict) or len(spec) != 1 or next(iter(spec)) not in DISTRIBUTIONS:
        raise _fail(source, field, "{ uniform = [lo, hi] }, { normal = [mean, sd] } or "
                    "{ choice = [...] }", spec)  # fmt: skip
    kind, args = next(iter(spec.items()))
    if not isinstance(args, list) or not args:
        raise _fail(source, f"{field}.{kind}", "a non-empty list", args)
    if kind != "choice":
        if len(args) != 2 or not all(_number(a) for a in args):
            raise _fail(source, f"{field}.{kind}", "two numbers", args)
        if kind == "uniform" and args[1] < args[0]:
            raise _fail(source, f"{field}.{kind}", "[lo, hi] with lo <= hi", args)
        if kind == "uniform" and not math.isfinite(args[1] - args[0]):
            raise _fail(source, f"{field}.{kind}", "[lo, hi] with a finite width hi - lo", args)
        if kind == "normal" and args[1] < 0:
            raise _fail(source, f"{field}.{kind}", "[mean, sd] with sd >= 0", args)
    return kind, args


def _draw(rng: np.random.Generator, kind: str, args: list, n: int) -> list:
    if kind == "uniform":
        return [float(x) for x in rng.uniform(args[0], args[1], n)]
    if kind == "normal":
        return [float(x) for x in rng.normal(args[0], args[1], n)]
    return [args[int(i)] for i in rng.integers(0, len(args), n)]


def _set(data: dict, path: str, value: Any) -> None:
    *tables, last = path.split(".")
    for t in tables:
        data = data.setdefault(t, {})
        if not isinstance(data, dict):
            raise ValueError(f"'{t}' of '{path}' is not a table in the base scenario")
    data[last] = value


def _merge(into: dict, overlay: dict) -> None:
    for k, v in overlay.items():
        if isinstance(v, dict) and isinstance(into.get(k), dict):
            _merge(into[k], v)
        else:
            into[k] = copy.deepcopy(v)


def _base(source: str, ref: Any, here: Path) -> tuple[dict, Path]:
    if not isinstance(ref, str):
        raise _fail(source, "base", "a shipped scenario name or a scenario file", ref)
    path = here / ref
    if not path.is_file():
        path = scenarios.SCENARIO_DIR / f"{ref}.toml"
    if not path.is_file():
        known = ", ".join(scenarios.shipped_names())
        raise _fail(source, "base", f"a scenario file or one of {known}", ref)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise CampaignError(f"{source}: field 'base': cannot read {path}: {exc}") from None
    data.setdefault("name", path.stem)
    for comp in data.get("command", {}).get("component", []):  # CSV tables wherever we write
        if isinstance(comp, dict) and comp.get("kind") == "csv" and "path" in comp:
            comp["path"] = str((path.parent / comp["path"]).resolve())
    return data, path.parent


def load(path: Path) -> Campaign:
    source = str(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise CampaignError(f"{source}: cannot read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise CampaignError(f"{source}: not valid TOML: {exc}") from None
    found = _non_finite(data)
    if found is not None:
        raise _fail(source, found[0], "a finite number (NaN and inf are refused)", found[1])
    known = {"name", "description", "base", "duration_s", "seed", "samples", "nominal", "sample",
             "sweep", "variant", "invariants"}  # fmt: skip
    for key in data:
        if key not in known:
            raise CampaignError(
                f"{source}: unknown field '{key}' (known: {', '.join(sorted(known))})"
            )
    name = data.get("name", path.stem)
    description = data.get("description", "")
    if not isinstance(name, str) or not isinstance(description, str):
        raise _fail(source, "name", "a string", name)
    base, base_dir = _base(source, data.get("base"), path.parent)
    if "duration_s" in data:
        if not _number(data["duration_s"]) or data["duration_s"] <= 0:
            raise _fail(source, "duration_s", "a positive number", data["duration_s"])
        base["duration_s"] = data["duration_s"]
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise _fail(source, "seed", "a non-negative integer", seed)
    n = data.get("samples", 0)
    if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= 1_000_000:
        raise _fail(source, "samples", "an integer in 0..1000000", n)
    nominal = data.get("nominal", n == 0)
    if not isinstance(nominal, bool):
        raise _fail(source, "nominal", "true or false", nominal)
    sample = data.get("sample", {})
    if not isinstance(sample, dict):
        raise _fail(source, "sample", "a table of field = distribution", sample)
    if sample and n == 0:
        raise _fail(source, "samples", "a number of samples for [sample]", n)
    dists = {k: _distribution(source, k, v) for k, v in sorted(sample.items())}
    sweep = data.get("sweep", {})
    if not isinstance(sweep, dict):
        raise _fail(source, "sweep", "a table of field = [values]", sweep)
    for k, v in sweep.items():
        if not isinstance(v, list) or not v:
            raise _fail(source, f"sweep.{k}", "a non-empty list of values", v)
    variants = data.get("variant", [])
    if not isinstance(variants, list) or not all(isinstance(v, dict) for v in variants):
        raise _fail(source, "variant", "a list of tables ([[variant]])", variants)
    for i, v in enumerate(variants):
        if not isinstance(v.get("name"), str):
            raise _fail(source, f"variant[{i}].name", "a string", v.get("name"))
    invariants = _invariants(source, data.get("invariants", {}))

    combinations = math.prod(len(v) for v in sweep.values())
    total = (n + nominal) * max(1, len(variants)) * combinations
    if total > MAX_CASES:
        raise _fail(source, "samples", f"a campaign of at most {MAX_CASES} runs (samples, "
                    "nominal, variants and sweep combinations multiplied)", total)  # fmt: skip

    rng = np.random.Generator(np.random.PCG64(seed))
    draws = {k: _draw(rng, kind, args, n) for k, (kind, args) in dists.items()}
    for k, values in draws.items():
        if not all(math.isfinite(v) for v in values if isinstance(v, float)):
            raise _fail(source, f"sample.{k}", "a distribution whose draws are finite", sample[k])
    base_seed = base.get("seed", 0)
    samples = ([-1] if nominal else []) + list(range(n))
    combos = list(itertools.product(*sweep.values())) or [()]
    axes = (*(["variant"] if variants else []), *sweep, *dists)
    if "seed" not in axes:
        axes = (*axes, "seed")
    cases = []
    for s in samples:
        for variant in variants or [None]:
            for combo in combos:
                values: dict[str, Any] = {}
                case = copy.deepcopy(base)
                if variant is not None:
                    _merge(case, {k: v for k, v in variant.items() if k != "name"})
                    values["variant"] = variant["name"]
                values.update(zip(sweep, combo, strict=True))
                if s >= 0:
                    values.update({k: draws[k][s] for k in dists})
                    values.setdefault("seed", seed * 1_000_003 + s)
                values.setdefault("seed", base_seed)
                run_id = f"{len(cases):05d}"
                for k, v in values.items():
                    if k != "variant":
                        try:
                            _set(case, k, v)
                        except ValueError as exc:
                            raise CampaignError(f"{source}: run {run_id}: {exc}") from None
                case["name"] = f"{name}-{run_id}"
                text = dumps(case)
                where = (
                    f"{source} (run {run_id}: "
                    + ", ".join(f"{k}={v!r}" for k, v in values.items())
                    + ")"
                )
                try:
                    scenarios.parse(text, where, base_dir)
                except scenarios.ScenarioError as exc:
                    raise CampaignError(str(exc)) from None
                digest = hashlib.sha256(text.encode()).hexdigest()[:16]
                cases.append(Case(run_id, s, values, text, digest))
    return Campaign(name, description, path, axes, tuple(cases), invariants)


def _invariants(source: str, table: Any) -> Invariants:
    if not isinstance(table, dict):
        raise _fail(source, "invariants", "a table", table)
    out = Invariants()
    values = {}
    for key, value in table.items():
        if key not in Invariants.__dataclass_fields__:
            known = ", ".join(Invariants.__dataclass_fields__)
            raise CampaignError(f"{source}: unknown field 'invariants.{key}' (known: {known})")
        default = getattr(out, key)
        if isinstance(default, bool) != isinstance(value, bool) or not (
            isinstance(value, bool) or _number(value)
        ):
            raise _fail(source, f"invariants.{key}", type(default).__name__, value)
        values[key] = value
    return Invariants(**values)
