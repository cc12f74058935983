"""The shared pieces of BENCHMARKS.md's sections: number formatting, markdown tables, verdicts,
and the measurement stamp under a heading. Each section module draws its own table with them."""
from __future__ import annotations

import math


def f(x, digits: int = 3, *, fmt: str | None = None) -> str:
    """A number for a table: ``digits`` decimals, or the format spec ``fmt`` (``.4e``); 'n/a' for
    None or NaN; integers as they are (without ``fmt``)."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "n/a"
    if fmt is not None:
        return format(x, fmt)
    return f"{x:.{digits}f}" if isinstance(x, float) else str(x)


def table(header: list[str], rows: list[list]) -> list[str]:
    """Markdown table lines."""
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return out + ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]


def yes(ok) -> str:
    """``ok`` may come back from JSON as a string (numpy booleans were stored as text)."""
    return "**met**" if ok in (True, "True") else "**not met**"


def stamped(lines: list[str], rec: dict) -> list[str]:
    """A section's lines with the date and commit of its measurement under its heading (and its
    device, measured on a GPU)."""
    if not lines:
        return lines
    where = f" on {rec['device']}" if str(rec.get("variant", "")).startswith("cuda") else ""
    note = (f"_Measured {rec['date']} at commit {rec['git']}{where} ({rec['sizes']} sizes, "
            f"{rec['wall_s'] / 60:.1f} min)._")
    return lines[:1] + ["", note] + lines[1:]
