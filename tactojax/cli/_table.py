"""Plain-text tables and JSON output shared by the sub-commands."""

from __future__ import annotations

import json
from pathlib import Path


def format_table(headers: list[str], rows: list[list]) -> str:
    """A left-aligned text table."""
    cells = [[str(h) for h in headers]] + [[_cell(v) for v in row] for row in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(headers))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _cell(value) -> str:
    if isinstance(value, float):
        return f"{value:.3f}" if abs(value) < 1000 else f"{value:.0f}"
    return str(value)


def write_json(path: str | Path, payload: dict) -> None:
    """Write ``payload`` as JSON atomically (no half-written file on a crash)."""
    from tactojax.storage import atomic_write_bytes

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, (json.dumps(payload, indent=2, default=str) + "\n").encode())
