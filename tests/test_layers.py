"""Dependencies point one way: sil and tools use ecu, plant and protocol; plant uses protocol;
the firmware (ecu) uses protocol only; the contract (protocol) uses nothing of ours. Every import
counts, including those inside functions."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = {"ecu", "plant", "protocol", "sil", "tools"}
ALLOWED = {
    "protocol": set(),
    "ecu": {"protocol"},
    "plant": {"protocol"},
}


def imported_packages(path: Path) -> dict[str, int]:
    """Our top-level packages imported by a module, with the first line of each."""
    found: dict[str, int] = {}
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        for name in names:
            top = name.split(".")[0]
            if top in OURS:
                found.setdefault(top, node.lineno)
    return found


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_only_what_it_may(package: str) -> None:
    files = sorted((ROOT / package).rglob("*.py"))
    assert files, f"no modules found in {package}/"
    wrong = [
        f"{f.relative_to(ROOT)}:{line} imports {top}"
        for f in files
        for top, line in imported_packages(f).items()
        if top != package and top not in ALLOWED[package]
    ]
    assert not wrong, "\n".join(wrong)


def test_nothing_imports_tools() -> None:
    """tools/ holds thin utilities (the vcan VM, probes) that use the packages; no package and
    no other tool reaches back into it."""
    files = [f for p in sorted(OURS - {"tools"}) for f in sorted((ROOT / p).rglob("*.py"))]
    files += sorted((ROOT / "tools").rglob("*.py"))
    assert files
    wrong = [
        f"{f.relative_to(ROOT)}:{line} imports tools"
        for f in files
        for top, line in imported_packages(f).items()
        if top == "tools"
    ]
    assert not wrong, "\n".join(wrong)


# sil/ by rooms, each importing only rooms below it: bench and commands on top, nothing below
# them imports them
_BASE = {"validation", "busfault"}
_RECORDS = _BASE | {"scenario", "record", "analysis"}
_RUNS = _RECORDS | {"run"}
SIL_ROOMS = {
    "validation": set(),
    "busfault": {"validation"},
    "scenario": {"busfault", "validation"},
    "record": {"scenario", "busfault", "validation"},
    "analysis": {"record", "scenario", "busfault", "validation"},
    "console": {"record", "scenario", "busfault", "validation"},
    "run": _RECORDS,
    "campaign": _RUNS,
    "verify": _RUNS,
    "bench": _RUNS | {"campaign", "verify", "console"},
    "commands": _RUNS | {"campaign", "verify", "console", "bench"},
    "cli": {"commands", "validation"},
}


def _room(path: Path) -> str:
    parts = path.relative_to(ROOT / "sil").parts
    return parts[0] if len(parts) > 1 else path.stem


def test_sil_rooms_import_only_the_rooms_below_them() -> None:
    files = [f for f in sorted((ROOT / "sil").rglob("*.py")) if f.name != "__init__.py"
             or f.parent != ROOT / "sil"]  # fmt: skip
    rooms = {_room(f) for f in files}
    assert rooms == set(SIL_ROOMS), f"rooms without a rule: {rooms ^ set(SIL_ROOMS)}"
    wrong = []
    for f in files:
        room = _room(f)
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [f"{node.module}.{a.name}" for a in node.names] if node.module == "sil" \
                    else [node.module]  # fmt: skip
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for name in names:
                parts = name.split(".")
                if parts[0] == "sil" and len(parts) > 1 and parts[1] != room:
                    if parts[1] not in SIL_ROOMS[room]:
                        wrong.append(f"{f.relative_to(ROOT)}:{node.lineno} ({room}) imports {name}")
    assert not wrong, "\n".join(wrong)


def test_sil_has_about_a_dozen_modules_at_its_top() -> None:
    top = [p for p in (ROOT / "sil").iterdir() if p.suffix == ".py" or (p / "__init__.py").exists()]
    assert len(top) <= 13, sorted(p.name for p in top)
