"""Write a matplotlib figure as a PNG, atomically."""

from __future__ import annotations

from pathlib import Path

from tactojax.storage import atomic_open


def save_png(figure, path: str | Path, *, dpi: int = 100) -> Path:
    """Lay out ``figure`` tightly, unless it has a layout engine of its own, and write it to
    ``path`` (parent folders created; never half-written)."""
    if figure.get_layout_engine() is None:
        figure.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path, "wb") as handle:
        figure.savefig(handle, format="png", dpi=dpi)
    return path
