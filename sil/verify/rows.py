"""The rows of `sil verify`: one published number each, with its source, the reading it was run
in, the published, predicted and reached values, the tolerance and ok."""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass
class Row:
    name: str
    source: str
    reading: str
    published: float | None
    reached: float
    tolerance: str | None
    ok: bool
    predicted: float | None = None
    note: str = ""


def check(
    name: str,
    source: str,
    reading: str,
    published: float | None,
    reached: float,
    tol: float,
    relative: bool,
    *,
    against: float | None = None,
    predicted: float | None = None,
    note: str = "",
) -> Row:
    """``reached`` within ``tol`` of ``predicted`` if given, else of ``against`` (default: the
    published value)."""
    target = predicted if predicted is not None else (published if against is None else against)
    assert target is not None
    bound = tol * abs(target) if relative else tol
    return Row(
        name,
        source,
        reading,
        published,
        reached,
        f"{tol * 100:g} %" if relative else f"{tol:g} abs",
        bool(abs(reached - target) <= bound),
        predicted,
        note,
    )


def at_least(name: str, source: str, reached: float, minimum: float, note: str) -> Row:
    """A claim in words, checked as a figure that must reach ``minimum``."""
    return Row(
        name, source, "-", None, reached, f">= {minimum:g}", bool(reached >= minimum), None, note
    )


def info(name: str, source: str, reading: str, reached: float, note: str) -> Row:
    """A figure shown for understanding, not checked."""
    return Row(name, source, reading, None, reached, None, True, None, note)


def rel(a: float, b: float) -> float:
    """|a - b| relative to |b|."""
    return abs(a - b) / max(abs(b), 1e-12)


def as_dicts(rows: list[Row]) -> list[dict]:
    return [asdict(r) for r in rows]


def format_table(rows: list[Row]) -> str:
    """A plain-text table of the rows; notes and sources below it, numbered."""

    def num(x: object) -> str:
        return "-" if x is None else (f"{x:.5g}" if isinstance(x, float) else str(x))

    width = max(len(r.name) for r in rows)
    head = (
        f"{'check':<{width}}  {'reading':<11}  {'published':>10}  {'predicted':>10}  "
        f"{'reached':>10}  {'tolerance':>9}  ok"
    )
    lines = [head]
    notes: list[str] = []
    for r in rows:
        mark = ""
        if r.note:
            if r.note not in notes:
                notes.append(r.note)
            mark = f" [{notes.index(r.note) + 1}]"
        lines.append(
            f"{r.name:<{width}}  {r.reading:<11}  {num(r.published):>10}  {num(r.predicted):>10}  "
            f"{num(r.reached):>10}  {num(r.tolerance):>9}  {'yes' if r.ok else 'NO'}{mark}"
        )
    lines.append("")
    lines.extend(f"[{k}] {n}" for k, n in enumerate(notes, 1))
    sources = sorted({r.source for r in rows})
    lines.append("sources: " + "; ".join(sources))
    return "\n".join(lines)
