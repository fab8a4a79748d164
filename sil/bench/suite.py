"""`sil bench all`: every bench in one run, and the page of figures the docs link to.

Each bench (sil.commands.bench.TARGETS) runs in turn, quick unless asked otherwise; a bench that
fails is reported as failed and the others still run. The result names the machine (CPU model,
cores, load average before and after, Python, OS) and gives each bench's figures with its
targets: a figure whose key ends in ``target_met`` or is ``targets_met`` says whether the bench
met the target it states. :func:`markdown` writes that as the page docs/benchmarks.md.
"""

from __future__ import annotations

import datetime
import importlib
import os
import platform
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from types import ModuleType

from protocol import strict_json
from sil.bench import TARGETS


def machine() -> dict:
    """What the figures were measured on."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu": model,
        "cores": os.cpu_count(),
        "load_average_1min": round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None,
        "python": platform.python_version(),
        "os": f"{platform.system()} {platform.release()}",
    }


def _description(module: ModuleType) -> str:
    """The first paragraph of the bench module's docstring, on one line."""
    return " ".join((module.__doc__ or "").strip().split("\n\n")[0].split())


def targets_of(figures: dict) -> dict[str, bool]:
    """The bench's own verdicts: ``targets_met`` (a dict or one bool) and every ``*target_met``."""
    out: dict[str, bool] = {}
    for key, value in figures.items():
        if key == "targets_met" and isinstance(value, dict):
            out.update({k: bool(v) for k, v in value.items()})
        elif key.endswith("target_met") or key == "targets_met":
            out[key.removesuffix("_target_met").removesuffix("_met")] = bool(value)
    return out


def run_all(
    targets: dict[str, str],
    *,
    quick: bool = True,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """Run the benches ``targets`` (name -> module); the machine, then each bench's figures, its
    targets, its time, or its error."""
    out: dict = {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "mode": "quick" if quick else "full",
        "machine": machine(),
        "benches": {},
    }
    for name, module_name in targets.items():
        if progress is not None:
            progress(name)
        start = time.monotonic()
        entry: dict = {"what": ""}
        try:
            module = importlib.import_module(module_name)
            entry["what"] = _description(module)
            entry["target_text"] = dict(getattr(module, "TARGET_TEXT", {}))
            figures = module.run(quick=quick)
        except Exception as exc:  # noqa: BLE001 (one bench's failure must not lose the others)
            entry["error"] = f"{type(exc).__name__}: {exc}"
        else:
            entry["figures"] = figures
            entry["targets_met"] = targets_of(figures)
        entry["seconds"] = round(time.monotonic() - start, 1)
        out["benches"][name] = entry
    out["machine"]["load_average_1min_after"] = (
        round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None
    )
    return out


def _cell(value: object) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, dict | list):
        return strict_json.dumps(value).replace("|", "\\|")
    return str(value).replace("|", "\\|")


def _rows(figures: dict) -> Iterable[str]:
    for key, value in figures.items():
        if key == "targets_met" or key.endswith("target_met"):
            continue
        yield f"| `{key}` | {_cell(value)} |"


def markdown(result: dict) -> str:
    """The page: the machine, a summary of targets, then each bench's figures."""
    m = result["machine"]
    lines = [
        "# Benchmarks",
        "",
        "Written by `sil bench all --markdown docs/benchmarks.md` "
        f"({result['mode']} runs, {result['date']}); run it again to refresh this page. Each "
        "figure is what the bench printed on the machine below; every bench states its own "
        "targets, and `sil bench TARGET` runs one of them alone (`--json` for the figures).",
        "",
        "## Machine",
        "",
        f"- CPU: {m['cpu']}, {m['cores']} cores",
        f"- load average (1 min): {m['load_average_1min']} before, "
        f"{m.get('load_average_1min_after')} after",
        f"- Python {m['python']} on {m['os']}",
        "",
        "## Targets",
        "",
        "| bench | target | met |",
        "|---|---|---|",
    ]
    for name, entry in result["benches"].items():
        if "error" in entry:
            lines.append(f"| {name} | (the bench failed) | no |")
        text = entry.get("target_text", {})
        for target, met in entry.get("targets_met", {}).items():
            lines.append(f"| {name} | {text.get(target, target)} | {'yes' if met else '**no**'} |")
    for name, entry in result["benches"].items():
        lines += ["", f"## `sil bench {name}`", "", entry["what"], ""]
        if "error" in entry:
            lines += [f"The bench failed: `{entry['error']}`"]
            continue
        lines += ["| figure | value |", "|---|---|", *_rows(entry["figures"])]
        lines += ["", f"({entry['seconds']:g} s)"]
    return "\n".join(lines) + "\n"


_SECTION = "\n## `sil bench "


def _parts(page: str) -> tuple[str, dict[str, list[str]], dict[str, str]]:
    """A page :func:`markdown` wrote: its head (title, first paragraphs, machine), its target rows
    by bench and its sections by bench, in order."""
    head, _, rest = page.partition("\n## Targets\n")
    table, *sections = rest.split(_SECTION)
    rows: dict[str, list[str]] = {}
    for line in table.splitlines():
        cells = line.split("|")
        if len(cells) > 2 and cells[1].strip() not in ("bench", "---", ""):
            rows.setdefault(cells[1].strip(), []).append(line)
    by_name = {sec.split("`", 1)[0]: _SECTION + sec.rstrip("\n") for sec in sections}
    return head.rstrip("\n"), rows, by_name


def merge(page: str, result: dict) -> str:
    """``page`` with the benches of ``result`` written anew (their target rows and sections
    replaced, or added in the registry's order), every other bench kept as it was measured; the
    head says which benches were refreshed, when, and on what machine."""
    head, rows, sections = _parts(page)
    _, new_rows, new_sections = _parts(markdown(result))
    rows.update(new_rows)
    sections.update(new_sections)
    m = result["machine"]
    names = ", ".join(f"`{n}`" for n in result["benches"])
    note = (
        f"Refreshed by `sil bench all --only ... --merge`: {names} ({result['mode']} runs, "
        f"{result['date']}, {m['cpu']}, {m['cores']} cores, load {m['load_average_1min']})."
    )
    order = [n for n in TARGETS if n in sections or n in rows]
    order += [n for n in [*sections, *rows] if n not in order]
    lines = [head, "", note, "", "## Targets", "", "| bench | target | met |", "|---|---|---|"]
    lines += [row for name in order for row in rows.get(name, [])]
    body = "".join(sections[name] + "\n" for name in order if name in sections)
    return "\n".join(lines) + "\n" + body


def print_progress(name: str) -> None:
    print(f"sil bench all: {name} ...", file=sys.stderr, flush=True)
