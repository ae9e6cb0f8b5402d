"""Crash-safe file writes: write a temporary file, fsync it, then rename it into place.

A reader (or a process restarted after SIGKILL or power loss) sees either the old file or the
complete new one, never a partial file. Temporary files live in the target's directory (so
that ``os.replace`` is an atomic rename on one filesystem) and their names start with
``.tmp-``, so that readers can ignore them and writers can clean them up.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

TMP_PREFIX = ".tmp-"


def fsync_directory(path: str | os.PathLike[str]) -> None:
    """Flush a directory entry (a rename or a new file) to disk where the OS allows it."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # Windows cannot open directories
        return
    try:
        os.fsync(fd)
    except OSError:  # some filesystems refuse fsync on a directory
        pass
    finally:
        os.close(fd)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "wb") -> Iterator[IO[Any]]:
    """Open a temporary file that replaces ``path`` atomically when the block exits cleanly.

    Args:
      path: final location; its directory must exist.
      mode: ``"wb"`` (bytes) or ``"w"`` (UTF-8 text).

    On an exception inside the block the temporary file is removed and ``path`` is untouched.
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"atomic_open supports mode 'wb' or 'w', got {mode!r}")
    target = Path(path)
    fd, tmp_name = tempfile.mkstemp(prefix=f"{TMP_PREFIX}{target.name}-", dir=target.parent)
    try:
        os.chmod(tmp_name, 0o666 & ~_umask())  # as open() would create it (mkstemp uses 0600)
        with open(fd, mode, **({} if "b" in mode else {"encoding": "utf-8"})) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp_name, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        raise
    fsync_directory(target.parent)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file, fsync, ``os.replace``)."""
    with atomic_open(path, "wb") as handle:
        handle.write(data)
