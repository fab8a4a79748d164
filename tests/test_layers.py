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
