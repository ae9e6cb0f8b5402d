"""Plain-text tables and JSON output: the one writer of the sub-commands and the benchmarks."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any


def format_table(headers: Sequence[str], rows: Sequence[Sequence[Any]], *, significant: int | None = None) -> str:
    """A left-aligned text table with a rule under the headers.

    Args:
        headers: column titles.
        rows: one sequence of cells per row; None prints as ``-``.
        significant: floats with this many significant digits (the benchmarks: timings span
            seconds to microseconds); default 3 decimals. Large floats print as integers.
    """
    cells = [[str(h) for h in headers]] + [[_cell(v, significant) for v in row] for row in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(headers))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _cell(value: Any, significant: int | None) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        if significant is None:
            return f"{value:.3f}" if abs(value) < 1000 else f"{value:.0f}"
        return f"{value:.{significant}g}" if abs(value) < 10.0 ** (significant + 1) else f"{value:.0f}"
    return str(value)


def write_json(path: str | Path, payload: dict) -> None:
    """Write ``payload`` as indented JSON atomically (no half-written file on a crash)."""
    from tactojax.storage import atomic_write_bytes

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, (json.dumps(payload, indent=2, default=str) + "\n").encode())


def share_with_interval(summary: dict) -> str:
    """An evaluation row's share within 2 mm with its 95 % interval, e.g. ``81 % [64, 91]``."""
    low, high = summary["within_2mm_interval"]
    return f"{100 * summary['within_mm']['2']:.0f} % [{100 * low:.0f}, {100 * high:.0f}]"
