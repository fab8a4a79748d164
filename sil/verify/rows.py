"""The rows of `sil verify`: one published number each, with its source, the reading it was run
in, the published, predicted and reached values, the tolerance and ok.

A row is checked (ok: within its tolerance of the published or predicted value), a claim in
words checked as a figure, a figure shown for understanding, or explained: a published number
that no engine with the plant's structure can give, shown next to what the run reached, with the
reason in its note; the figures that the reason rests on are checked in rows of their own."""

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
    explained: bool = False


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


def explained(
    name: str, source: str, reading: str, published: float, reached: float, note: str
) -> Row:
    """A published number this engine cannot give, for the reason in ``note``: not checked."""
    return Row(name, source, reading, published, reached, None, True, None, note, True)


def rel(a: float, b: float) -> float:
    """|a - b| relative to |b|."""
    return abs(a - b) / max(abs(b), 1e-12)


def as_dicts(rows: list[Row]) -> list[dict]:
    return [asdict(r) for r in rows]


def _verdict(r: Row) -> str:
    if r.explained:
        return "explained"
    if r.tolerance is None:
        return "-"  # shown for understanding
    return "yes" if r.ok else "NO"


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
            f"{num(r.reached):>10}  {num(r.tolerance):>9}  {_verdict(r)}{mark}"
        )
    failing = sum(not r.ok for r in rows)
    expl = sum(r.explained for r in rows)
    lines.append(
        f"{len(rows)} rows: {len(rows) - failing - expl} ok, {expl} explained, {failing} failing"
    )
    lines.append("")
    lines.extend(f"[{k}] {n}" for k, n in enumerate(notes, 1))
    sources = sorted({r.source for r in rows})
    lines.append("sources: " + "; ".join(sources))
    return "\n".join(lines)
