"""What shaped a run, kept in its folder so that the run can be replayed and repeated.

``sil run`` writes, before the run begins:

- ``scenario.toml``: the scenario as run: the file itself when nothing overrode it, else the
  file's fields with the run's seed, controller (``--controller``, ``--preset``, ``--reading``,
  ``--param``), duration and stop time, and CSV paths made absolute;
- ``commissioning.json``: a copy of the ``--commission`` file, if one was given;
- ``run.json``: the command line, the seed, the overrides, the mode, bus and ECU implementation,
  and the names of those two files.

They are read before the folder is cleared (:func:`prepare`), so that a run may take the
scenario or commissioning file from an earlier run in the same folder. ``sil replay LOG
--into-ecu`` reads them from the folder of the log (:func:`load`).
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from protocol import strict_json
from sil.record.results import write_atomically
from sil.scenario import Scenario

RECORD = "run.json"
SCENARIO = "scenario.toml"
COMMISSIONING = "commissioning.json"
FORMAT = "turbojet-sil run 1"


@dataclass(frozen=True)
class Overrides:
    """Command-line changes to a scenario's controller (None: the scenario's own)."""

    controller: str | None = None
    preset: str | None = None
    reading: str | None = None
    params: Mapping[str, float] = field(default_factory=dict)

    def apply(self, s: Scenario) -> Scenario:
        """``s`` with these changes."""
        c = s.controller
        return replace(
            s,
            controller=replace(
                c,
                kind=self.controller or c.kind,
                preset=self.preset or c.preset,
                reading=self.reading or c.reading,
                params={**c.params, **self.params},
            ),
        )

    def as_dict(self) -> dict[str, Any]:
        """The overrides given, by option name."""
        out: dict[str, Any] = {
            k: v
            for k, v in (
                ("controller", self.controller),
                ("preset", self.preset),
                ("reading", self.reading),
            )
            if v is not None
        }
        if self.params:
            out["params"] = dict(self.params)
        return out


@dataclass(frozen=True)
class RunRecord:
    """A run folder's record, as :func:`load` reads it."""

    folder: Path
    data: dict[str, Any]

    @property
    def scenario(self) -> Path:
        return self.folder / self.data.get("scenario_file", SCENARIO)

    @property
    def commissioning(self) -> Path | None:
        name = self.data.get("commissioning_file")
        return None if name is None else self.folder / name

    @property
    def mode(self) -> str:
        return str(self.data.get("mode", "lockstep"))

    @property
    def ecu_impl(self) -> str:
        return str(self.data.get("ecu_impl", "python"))


@dataclass
class Pending:
    """A run's record, read before the run folder is cleared (the scenario or commissioning
    file may be an earlier run's copy in that folder) and written into it by :meth:`write`."""

    record: dict[str, Any]
    scenario_text: str | None
    commissioning: bytes | None
    error: str | None = None  # why a file could not be read (raised by write)

    def check(self) -> None:
        """ValueError naming the scenario or commissioning file that could not be read."""
        if self.error is not None:
            raise ValueError(self.error)

    def write(self, out_dir: Path) -> dict[str, Any]:
        """Write scenario.toml, commissioning.json and run.json into ``out_dir``, each
        atomically (:class:`sil.record.results.WriteError` names a file that cannot be written); the
        record."""
        self.check()
        if self.scenario_text is not None:
            write_atomically(out_dir / SCENARIO, self.scenario_text)
        if self.commissioning is not None:
            write_atomically(out_dir / COMMISSIONING, self.commissioning)
        write_atomically(out_dir / RECORD, strict_json.dumps(self.record, indent=2) + "\n")
        return self.record


def prepare(s: Scenario, seed: int, run: dict[str, Any], commission: Path | None) -> Pending:
    """The record of a run of ``s`` with ``seed`` (``run``: the options that shaped it, for
    ``run.json``; ``commission``: the ``--commission`` file)."""
    record: dict[str, Any] = {"format": FORMAT, "scenario": s.name, **run, "seed": seed}
    pending = Pending(record, None, None)
    if s.path is not None:
        record["scenario_source"] = str(s.path)
        record["scenario_file"] = SCENARIO
        try:
            pending.scenario_text = scenario_text(s, seed)
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            pending.error = f"{s.path}: cannot read the scenario file: {exc}"
    if commission is not None:
        record["commission_source"] = str(commission)
        record["commissioning_file"] = COMMISSIONING
        try:
            pending.commissioning = commission.read_bytes()
        except OSError as exc:
            pending.error = f"{commission}: cannot read the commissioning file: {exc.strerror}"
    return pending


def load(folder: Path) -> RunRecord | None:
    """The record of the run folder ``folder``, or None when it has none."""
    path = folder / RECORD
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a run record: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError(f"{path}: not a run record (expected format '{FORMAT}')")
    return RunRecord(folder, data)


def scenario_text(s: Scenario, seed: int) -> str:
    """The scenario file as run: its own text when ``s`` and ``seed`` are what it says, else
    its fields with those of ``s`` that a run may change, as TOML."""
    assert s.path is not None
    text = s.path.read_text(encoding="utf-8")
    data = tomllib.loads(text)
    ran = _as_run(data, s, seed)
    if ran == data:
        return text
    ran = {"name": s.name, **ran}  # (a file without a name took its own)
    head = f"# the scenario {s.name} as run, from {s.path}\n"
    return head + "\n".join(_toml(ran)) + "\n"


def _as_run(data: dict[str, Any], s: Scenario, seed: int) -> dict[str, Any]:
    """The file's fields (``data``) with the run's seed, duration, rate, stop and controller."""
    assert s.path is not None
    ran = json.loads(json.dumps(data, default=str))  # a deep copy (TOML has no dates here)
    _set(ran, "duration_s", s.duration_s)
    _set(ran, "ecu_rate_hz", s.ecu_rate_hz, data.get("ecu_rate_hz", 100.0))
    _set(ran, "seed", seed, data.get("seed", 0))
    command = ran.setdefault("command", {})
    if s.stop_s is None:
        command.pop("stop_s", None)
    else:
        _set(command, "stop_s", s.stop_s)
    for component in command.get("component", []):
        if component.get("kind") == "csv" and "path" in component:
            component["path"] = str((s.path.parent / component["path"]).resolve())
    c = s.controller
    controller = ran.setdefault("controller", {})
    _set(controller, "kind", c.kind, controller.get("kind", "mrac"))
    for key, value in (("preset", c.preset), ("reading", c.reading)):
        if value is None:
            controller.pop(key, None)
        else:
            controller[key] = value
    params = {k: list(v) if isinstance(v, tuple) else v for k, v in c.params.items()}
    if params != controller.get("params", {}):
        controller["params"] = params
    if not controller:
        del ran["controller"]
    return ran


def _set(table: dict[str, Any], key: str, value: Any, default: Any = None) -> None:
    """Set ``table[key]`` to ``value`` unless it holds that value already (or, missing, its
    ``default`` is that value): a file's ``30`` stays ``30`` for a run of 30.0."""
    if table.get(key, default) != value:
        table[key] = value


def _toml(table: dict[str, Any], prefix: str = "") -> list[str]:
    """TOML lines for ``table``: its values, then its tables and arrays of tables."""
    lines = [f"{_key(k)} = {_value(v)}" for k, v in table.items() if not _nested(v)]
    for key, value in table.items():
        name = f"{prefix}{_key(key)}"
        if isinstance(value, dict):
            lines += ["", f"[{name}]", *_toml(value, f"{name}.")]
        elif _nested(value):
            for item in value:
                lines += ["", f"[[{name}]]", *_toml(item, f"{name}.")]
    return lines


def _nested(value: Any) -> bool:
    """A table or an array of tables (written under a header, not inline)."""
    return isinstance(value, dict) or (
        isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)
    )


def _key(key: str) -> str:
    bare = key.replace("_", "").replace("-", "").isalnum() and key.isascii()
    return key if bare else json.dumps(key)


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        return repr(value) if math.isfinite(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"no TOML for {value!r}")
