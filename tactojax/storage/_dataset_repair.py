"""Repair a dataset with corrupt chunks: keep every intact record, say exactly what is lost.

The repair rewrites ``manifest.json`` atomically without the chunks that fail their check
(missing, truncated, modified, unreadable, or not the manifest's shapes), so the dataset is at
every moment either the old one or the repaired one. Intact chunk files are not touched. The
bad files are moved to ``DIR/corrupt/`` (kept for inspection, never deleted), and the manifest's
metadata gains a ``"repairs"`` entry listing each lost chunk and its record count.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

from tactojax.storage._atomic import atomic_write_bytes, fsync_directory
from tactojax.storage._dataset import (
    FORMAT, MANIFEST, VERSION, ChunkProblem, Dataset, _acquire_lock, _read_manifest,
)

CORRUPT_DIR = "corrupt"
"""Where a repair moves the bad chunk files, inside the dataset directory."""


@dataclass(frozen=True)
class DatasetRepair:
    """What :func:`repair_dataset` found and did."""

    path: Path
    lost: tuple[ChunkProblem, ...]
    """The chunks dropped from the dataset (empty: nothing to repair)."""
    kept_chunks: int
    kept_records: int
    moved_to: tuple[Path | None, ...]
    """Where each lost chunk's file went (None: it was missing, or ``dry_run``)."""
    dry_run: bool = False

    @property
    def lost_records(self) -> int:
        return sum(chunk.count for chunk in self.lost)

    def as_dict(self) -> dict:
        """JSON-ready."""
        return {"path": str(self.path), "dry_run": self.dry_run, "kept_chunks": self.kept_chunks,
                "kept_records": self.kept_records, "lost_records": self.lost_records,
                "lost": [{**asdict(chunk), "moved_to": None if moved is None else str(moved)}
                         for chunk, moved in zip(self.lost, self.moved_to, strict=True)]}


def repair_dataset(path: str | os.PathLike[str], *, dry_run: bool = False) -> DatasetRepair:
    """Drop a dataset's corrupt chunks, keeping every intact record (see the module docstring).

    Args:
        path: dataset directory. Its lock is taken, so no writer can run meanwhile.
        dry_run: only check and report; change nothing.

    Returns:
        The chunks lost (with their record counts) and what is kept.

    Raises:
        FileNotFoundError, ValueError: not a dataset, or its manifest itself is unreadable
            (then nothing can say which records existed, and nothing is changed).
        DatasetLockedError: a writer is running.
    """
    root = Path(path)
    Dataset(root)  # a clear error for a missing directory or a bad manifest, before locking
    lock = _acquire_lock(root)
    try:
        manifest = _read_manifest(root)
        dataset = Dataset(root)
        lost = dataset.check()
        bad_files = {chunk.file for chunk in lost}
        kept = [entry for entry in manifest["chunks"] if entry["file"] not in bad_files]
        report = DatasetRepair(root, tuple(lost), len(kept), sum(entry["count"] for entry in kept),
                               (None,) * len(lost), dry_run)
        if not lost or dry_run:
            return report
        metadata = dict(manifest["metadata"])
        metadata["repairs"] = [*metadata.get("repairs", []), {
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "lost": [{"file": c.file, "records": c.count, "reason": c.reason} for c in lost]}]
        repaired = {"format": FORMAT, "version": VERSION, "metadata": metadata,
                    "schema": manifest["schema"], "chunks": kept}
        atomic_write_bytes(root / MANIFEST, json.dumps(repaired, indent=1).encode())
        return DatasetRepair(root, tuple(lost), len(kept), report.kept_records,
                             tuple(_move_aside(root, chunk.file) for chunk in lost))
    finally:
        with contextlib.suppress(OSError):
            lock.unlink()


def _move_aside(root: Path, file: str) -> Path | None:
    """Move an unlisted bad chunk into ``root/corrupt/`` (never overwriting); None if missing."""
    source = root / file
    if not source.is_file():
        return None
    folder = root / CORRUPT_DIR
    folder.mkdir(exist_ok=True)
    target, copy = folder / source.name, 1
    while target.exists():
        target, copy = folder / f"{source.stem}.{copy}{source.suffix}", copy + 1
    os.replace(source, target)
    fsync_directory(folder)
    return target
