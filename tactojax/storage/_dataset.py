"""On-disk datasets: fixed-shape records in compressed numpy chunks listed by a JSON manifest.

Format (version 1), readable with numpy and json alone. A dataset is a directory::

    manifest.json
    chunks/chunk-000000.npz
    chunks/chunk-000001.npz ...

``manifest.json`` is a JSON object:

- ``format``: the string ``"tactojax-dataset"``; ``version``: the integer ``1``.
- ``metadata``: a free JSON object given when the dataset was created (sensor name and spec,
  collection protocol, ...).
- ``schema``: ``{field: {"dtype": str, "shape": [int, ...]}}`` describing ONE record. ``dtype``
  is a numpy dtype name (``"float32"``, ``"uint8"``, ``"bool"``, ``"int64"``, ...) or ``"str"``
  (stored as a fixed-width numpy unicode array, ``<U{n}`` with ``n`` the longest string of the
  chunk). ``shape`` ``[]`` is a scalar.
- ``chunks``: ``[{"file": "chunks/chunk-000000.npz", "count": n, "sha256": hex}, ...]``, the
  completed chunks in record order. ``file`` is relative to the dataset directory and
  ``sha256`` is the hex digest of the file's bytes.

Each chunk is an ``np.savez_compressed`` archive (load with ``np.load(f, allow_pickle=False)``)
holding one array per schema field (member ``<field>.npy``), of shape ``(count, *shape)``:
record ``j`` of the chunk is ``array[j]``. Record ``i`` of the dataset is record
``i - sum(previous counts)`` of the chunk it falls in. Only chunks listed in the manifest
belong to the dataset: ignore other files, notably ``.tmp-*`` (writes in progress), chunk
files a killed writer left unlisted, and ``.lock`` (the pid of the live writer).

Writers make every file by writing ``.tmp-*``, fsync and ``os.replace``, and rewrite the
manifest only after the new chunk is in place, so a dataset killed at any moment still reads
back every chunk its manifest lists.

A chunk that does not match its manifest entry (missing, truncated, modified) is never skipped:
reading it raises :class:`CorruptChunkError` naming every such chunk, and
``tactojax.io.repair_dataset`` (``tactojax repair DIR``) rewrites the manifest without them.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import re
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tactojax.storage._atomic import TMP_PREFIX, atomic_write_bytes

FORMAT = "tactojax-dataset"
VERSION = 1
MANIFEST = "manifest.json"
LOCK = ".lock"
_CHUNK_RE = re.compile(r"chunk-(\d+)\.npz$")
_NUMERIC_KINDS = "biufc"

Schema = dict[str, dict[str, Any]]
Record = dict[str, np.ndarray]


class CorruptDatasetError(ValueError):
    """A manifest or chunk file is unreadable, truncated, or disagrees with the manifest."""


@dataclass(frozen=True)
class ChunkProblem:
    """A chunk listed in a manifest that cannot be read as the manifest describes it."""

    file: str
    """Its path relative to the dataset directory (``chunks/chunk-000003.npz``)."""
    count: int
    """Records the manifest lists in it."""
    first_record: int
    """Index of its first record in the dataset."""
    reason: str


class CorruptChunkError(CorruptDatasetError):
    """One or more chunks cannot be read; ``chunks`` names each, the message says how to repair."""

    def __init__(self, path: Path, chunks: list[ChunkProblem], total: int) -> None:
        self.path, self.chunks, self.total = Path(path), tuple(chunks), total
        lost = sum(c.count for c in chunks)
        items = "; ".join(f"{self.path / c.file}: {c.reason} (records {c.first_record}-"
                          f"{c.first_record + c.count - 1})" for c in chunks)
        noun, pronoun = ("a corrupt chunk", "it") if len(chunks) == 1 else (f"{len(chunks)} corrupt chunks", "them")
        super().__init__(f"dataset {self.path} has {noun}: {items}. `tactojax repair {self.path}` rewrites "
                         f"the dataset without {pronoun}, keeping the other {total - lost} of {total} records")


class DatasetLockedError(RuntimeError):
    """Another live writer holds the dataset's ``.lock``."""


def _normalize_schema(schema: Mapping[str, Mapping[str, Any]]) -> Schema:
    """Canonical schema: numpy dtype names, shapes as lists of ints; raises ValueError."""
    out: Schema = {}
    for name, spec in schema.items():
        try:
            dtype = "str" if spec["dtype"] == "str" else np.dtype(spec["dtype"]).name
            shape = [int(s) for s in spec["shape"]]
        except (KeyError, TypeError) as error:
            raise ValueError(f"schema field {name!r}: bad spec {spec!r} ({error})") from None
        if dtype != "str" and np.dtype(dtype).kind not in _NUMERIC_KINDS:
            raise ValueError(f"schema field {name!r}: dtype {dtype!r} is not bool/numeric/str")
        out[str(name)] = {"dtype": dtype, "shape": shape}
    if not out:
        raise ValueError("schema has no fields")
    return out


def infer_schema(record: Mapping[str, Any]) -> Schema:
    """Schema of one record: numpy's dtype of each value (``"str"`` for strings) and shape."""
    arrays = {name: np.asarray(value) for name, value in record.items()}
    return _normalize_schema({name: {"dtype": "str" if a.dtype.kind == "U" else a.dtype.name,
                                     "shape": list(a.shape)} for name, a in arrays.items()})


def _validate_record(record: Mapping[str, Any], schema: Schema) -> Record:
    """Cast one record to the schema's dtypes; ValueError naming the field on any mismatch."""
    missing, extra = sorted(set(schema) - set(record)), sorted(set(record) - set(schema))
    if missing or extra:
        raise ValueError(f"record fields do not match the schema: missing {missing}, "
                         f"unexpected {extra}; expected {sorted(schema)}")
    out = {}
    for name, spec in schema.items():
        array, shape = np.asarray(record[name]), tuple(spec["shape"])
        if array.shape != shape:
            raise ValueError(f"field {name!r}: expected shape {shape}, got {array.shape}")
        if spec["dtype"] == "str":
            if array.dtype.kind != "U":
                raise ValueError(f"field {name!r}: expected dtype str, got {array.dtype}")
            out[name] = array
            continue
        dtype = np.dtype(spec["dtype"])
        integers = array.dtype.kind in "iu" and dtype.kind in "iu"
        if array.dtype.kind not in _NUMERIC_KINDS or not (
            integers or np.can_cast(array.dtype, dtype, "same_kind")
        ):
            raise ValueError(f"field {name!r}: expected dtype {dtype}, got {array.dtype} "
                             "which does not cast safely")
        cast = array.astype(dtype)
        if integers and not np.array_equal(cast, array):
            raise ValueError(f"field {name!r}: values out of range for dtype {dtype}")
        out[name] = cast
    return out


def _acquire_lock(root: Path) -> Path:
    """Create ``root/.lock`` with O_EXCL holding our pid; take over the lock of a dead pid."""
    lock = root / LOCK
    for _ in range(3):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                text = lock.read_text().strip()
            except FileNotFoundError:  # released meanwhile
                continue
            try:
                os.kill(int(text), 0)  # signal 0: only checks that the process exists
            except ProcessLookupError:  # stale: its writer died (e.g. SIGKILL)
                lock.unlink(missing_ok=True)
                continue
            except (ValueError, PermissionError):  # being written, or another user's process
                pass
            raise DatasetLockedError(
                f"dataset {root} is being written by process {text or '?'}; if no writer is "
                f"running, delete {lock}") from None
        with os.fdopen(fd, "w") as handle:
            handle.write(f"{os.getpid()}\n")
            handle.flush()
            os.fsync(handle.fileno())
        return lock
    raise DatasetLockedError(f"could not lock dataset {root}: {lock} keeps reappearing")


def _read_manifest(root: Path) -> dict[str, Any]:
    """Parse and check ``root/manifest.json``."""
    path = root / MANIFEST
    if not root.is_dir():
        raise FileNotFoundError(f"{root} is not a tactojax dataset: no such directory")
    if not path.is_file():
        raise FileNotFoundError(f"{root} is not a tactojax dataset: no {MANIFEST}")
    try:
        manifest = json.loads(path.read_bytes())
    except (ValueError, UnicodeDecodeError) as error:
        raise CorruptDatasetError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise ValueError(f"{root} is not a tactojax dataset: {path} has no format {FORMAT!r}")
    if manifest.get("version") != VERSION:
        raise ValueError(f"{path}: unsupported dataset version {manifest.get('version')!r} "
                         f"(this tactojax reads version {VERSION})")
    try:
        manifest["schema"] = _normalize_schema(manifest["schema"])
        bad = [c for c in manifest["chunks"] if not (isinstance(c["file"], str) and isinstance(
            c["sha256"], str) and isinstance(c["count"], int) and c["count"] > 0)]
        if bad or not isinstance(manifest["metadata"], dict):
            raise ValueError(f"bad metadata or chunk entries {bad}")
    except (KeyError, TypeError, ValueError) as error:
        raise CorruptDatasetError(f"{path}: malformed manifest ({error!r})") from None
    return manifest


class DatasetWriter:
    """Append fixed-shape records to a dataset directory, one compressed chunk at a time.

    Args:
      path: dataset directory; created if missing, appended to if it holds a dataset.
      schema: ``{field: {"dtype": str, "shape": [int]}}`` of one record; None infers it from
        the first record (new dataset) or uses the stored one (existing dataset).
      metadata: JSON object stored in the manifest; for an existing dataset, keys present in
        both must have equal values, and new keys are added.
      chunk_size: records per chunk file.

    Use as a context manager: leaving the block (also on an exception) writes buffered records.
    """

    def __init__(self, path: str | os.PathLike[str], *, schema: Mapping[str, Any] | None = None,
                 metadata: Mapping[str, Any] | None = None, chunk_size: int = 64) -> None:
        if chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
        try:
            given_metadata = json.loads(json.dumps(dict(metadata or {})))
        except (TypeError, ValueError) as error:
            raise ValueError(f"metadata must be JSON-serialisable: {error}") from None
        given_schema = None if schema is None else _normalize_schema(schema)
        self.path, self.chunk_size = Path(path), chunk_size
        self.path.mkdir(parents=True, exist_ok=True)
        self._lock: Path | None = _acquire_lock(self.path)
        try:
            self._open(given_schema, given_metadata)
        except BaseException:
            self._release()
            raise

    def _open(self, schema: Schema | None, metadata: dict[str, Any]) -> None:
        (self.path / "chunks").mkdir(exist_ok=True)
        for stale in [*self.path.glob(TMP_PREFIX + "*"), *self.path.glob(f"chunks/{TMP_PREFIX}*")]:
            stale.unlink(missing_ok=True)  # left by a killed writer; we hold the lock
        self._buffer: list[Record] = []
        if (self.path / MANIFEST).exists():
            manifest = _read_manifest(self.path)
            old = manifest["schema"]
            if schema is not None and schema != old:
                notes = [f"{k!r}: stored {old.get(k)}, given {schema.get(k)}"
                         for k in {**old, **schema} if old.get(k) != schema.get(k)]
                raise ValueError(f"schema does not match the dataset at {self.path}: "
                                 + "; ".join(notes))
            stored = manifest["metadata"]
            clash = {k: (stored[k], v) for k, v in metadata.items() if stored.get(k, v) != v}
            if clash:
                raise ValueError(f"metadata does not match the dataset at {self.path} "
                                 f"(key: (stored, given)): {clash}")
            self._schema: Schema | None = manifest["schema"]
            self._metadata, self._chunks = {**stored, **metadata}, manifest["chunks"]
        else:
            self._schema, self._metadata, self._chunks = schema, metadata, []
            if schema is not None:
                self._write_manifest()
        numbers = [int(m.group(1)) for f in [*(c["file"] for c in self._chunks),
                                             *(p.name for p in (self.path / "chunks").iterdir())]
                   if (m := _CHUNK_RE.search(f))]
        self._next_chunk = max(numbers, default=-1) + 1

    @property
    def schema(self) -> Schema | None:
        """Schema of one record (None until the first record of a new inferred dataset)."""
        return self._schema

    def __len__(self) -> int:
        """Records written so far, buffered ones included."""
        return sum(c["count"] for c in self._chunks) + len(self._buffer)

    def append(self, record: Mapping[str, Any]) -> None:
        """Validate one record (``{field: array-like, scalar or str}``) and buffer it."""
        if self._lock is None:
            raise ValueError(f"writer for {self.path} is closed")
        if self._schema is None:
            self._schema = infer_schema(record)
        self._buffer.append(_validate_record(record, self._schema))
        if len(self._buffer) >= self.chunk_size:
            self.flush()

    def flush(self) -> None:
        """Write the buffered records as one chunk, then the manifest listing it."""
        if not self._buffer or self._schema is None:
            return
        arrays = {k: np.stack([r[k] for r in self._buffer]) for k in self._schema}
        stream = io.BytesIO()
        np.savez_compressed(stream, **arrays)
        data, name = stream.getvalue(), f"chunks/chunk-{self._next_chunk:06d}.npz"
        atomic_write_bytes(self.path / name, data)
        self._chunks.append({"file": name, "count": len(self._buffer),
                             "sha256": hashlib.sha256(data).hexdigest()})
        self._next_chunk += 1
        self._buffer = []
        self._write_manifest()

    def _write_manifest(self) -> None:
        manifest = {"format": FORMAT, "version": VERSION, "metadata": self._metadata,
                    "schema": self._schema, "chunks": self._chunks}
        atomic_write_bytes(self.path / MANIFEST, json.dumps(manifest, indent=1).encode())

    def _release(self) -> None:
        lock, self._lock = self._lock, None
        with contextlib.suppress(OSError):
            if lock is not None and lock.read_text().split()[:1] == [str(os.getpid())]:
                lock.unlink()

    def close(self) -> None:
        """Flush buffered records and release the lock; safe to call twice."""
        if self._lock is None:
            return
        try:
            self.flush()
        finally:
            self._release()

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()  # completed records are valid even if the block raised


class Dataset:
    """Read-only view of a dataset directory; see :func:`open_dataset`."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        manifest = _read_manifest(self.path)
        self.metadata: dict[str, Any] = manifest["metadata"]
        self.schema: Schema = manifest["schema"]
        self._chunks: list[dict[str, Any]] = manifest["chunks"]
        self._offsets = np.cumsum([0] + self.chunk_counts)
        self._cache: tuple[Any, Record] | None = None

    @property
    def fields(self) -> tuple[str, ...]:
        """Field names, in schema order."""
        return tuple(self.schema)

    @property
    def chunk_counts(self) -> list[int]:
        """Number of records in each chunk, in order."""
        return [c["count"] for c in self._chunks]

    def __len__(self) -> int:
        return int(self._offsets[-1])

    def _fields(self, fields: Iterable[str] | None) -> tuple[str, ...]:
        names = self.fields if fields is None else tuple(fields)
        unknown = [f for f in names if f not in self.schema]
        if unknown:
            raise KeyError(f"unknown fields {unknown}; dataset has {list(self.fields)}")
        return names

    def _load_chunk(self, index: int, fields: tuple[str, ...]) -> Record:
        """Arrays ``(count, *shape)`` of chunk ``index`` after checking its hash and shapes."""
        entry = self._chunks[index]
        path = self.path / entry["file"]

        def corrupt(reason: str) -> CorruptChunkError:
            problem = ChunkProblem(entry["file"], entry["count"], int(self._offsets[index]), reason)
            return CorruptChunkError(self.path, [problem], len(self))

        try:
            data = path.read_bytes()
        except OSError as error:
            raise corrupt(f"listed chunk cannot be read ({error.strerror or error})") from None
        if hashlib.sha256(data).hexdigest() != entry["sha256"]:
            raise corrupt(f"sha256 mismatch ({len(data)} bytes; file is truncated or modified)")
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as archive:
                arrays = {f: archive[f] for f in fields}
        except Exception as error:  # zip, npy and key errors all mean a bad chunk
            raise corrupt(f"unreadable chunk ({error!r})") from None
        for name, array in arrays.items():
            spec = self.schema[name]
            expected = (entry["count"], *spec["shape"])
            kind_ok = array.dtype.kind == "U" if spec["dtype"] == "str" else (
                array.dtype == np.dtype(spec["dtype"]))
            if array.shape != expected or not kind_ok:
                raise corrupt(f"field {name!r} is {array.dtype} {array.shape}, manifest says "
                              f"{spec['dtype']} {expected}")
        return arrays

    def check(self, fields: Iterable[str] | None = None) -> list[ChunkProblem]:
        """Every listed chunk that cannot be read as the manifest says ([] when all can).

        Reads every chunk (``fields``: the fields to decode, default all; the hash check
        covers the whole file either way).
        """
        names, problems = self._fields(fields), []
        for index in range(len(self._chunks)):
            try:
                self._load_chunk(index, names)
            except CorruptChunkError as error:
                problems.extend(error.chunks)
        return problems

    def _corrupt(self, fields: tuple[str, ...]) -> CorruptChunkError:
        """The error naming every corrupt chunk, once the first one was met (reads all chunks)."""
        return CorruptChunkError(self.path, self.check(fields), len(self))

    def iter_chunks(self, fields: Iterable[str] | None = None) -> Iterator[Record]:
        """Yield each chunk as ``{field: (count, *shape) array}``, in record order."""
        names = self._fields(fields)
        for index in range(len(self._chunks)):
            try:
                chunk = self._load_chunk(index, names)
            except CorruptChunkError:
                raise self._corrupt(names) from None
            yield chunk

    def read(self, fields: Iterable[str] | None = None,
             indices: slice | np.ndarray | Iterable[int] | None = None) -> Record:
        """Records as ``{field: (n, *shape) array}``, reading only the chunks they fall in.

        Args:
          fields: field names to read (default all).
          indices: a slice or integer array (negative counts from the end); default all.
        """
        names, n = self._fields(fields), len(self)
        if indices is None:
            indices = slice(None)
        wanted = (np.arange(n)[indices] if isinstance(indices, slice)
                  else np.asarray(indices, dtype=np.int64).reshape(-1))
        if np.any((wanted < -n) | (wanted >= n)):
            raise IndexError(f"indices out of range for a dataset of {n} records")
        wanted = np.where(wanted < 0, wanted + n, wanted)
        order = np.argsort(wanted, kind="stable")
        chunk_of = np.searchsorted(self._offsets, wanted[order], side="right") - 1
        pieces: dict[str, list[np.ndarray]] = {f: [] for f in names}
        for index in np.unique(chunk_of).tolist():
            rows = wanted[order][chunk_of == index] - self._offsets[index]
            if self._cache is None or self._cache[0] != (index, names):  # last chunk read
                try:
                    self._cache = ((index, names), self._load_chunk(index, names))
                except CorruptChunkError:
                    raise self._corrupt(names) from None
            for name, array in self._cache[1].items():  # fancy indexing copies
                pieces[name].append(array[rows])
        inverse = np.empty_like(order)
        inverse[order] = np.arange(len(order))
        out = {}
        for name in names:
            spec = self.schema[name]
            empty = np.empty((0, *spec["shape"]), "U1" if spec["dtype"] == "str" else spec["dtype"])
            out[name] = np.concatenate(pieces[name] or [empty])[inverse]
        return out

    def __getitem__(self, index: int) -> Record:
        """One record as ``{field: array of the schema shape}``."""
        record = self.read(indices=np.array([index]))
        return {name: array[0] for name, array in record.items()}

    def __repr__(self) -> str:
        return f"Dataset({str(self.path)!r}, records={len(self)}, fields={list(self.fields)})"


def open_dataset(path: str | os.PathLike[str]) -> Dataset:
    """Open a dataset directory read-only; FileNotFoundError/ValueError if it is not one."""
    return Dataset(path)


def dataset_summary(path: str | os.PathLike[str], *, group_by: str | None = "object_id"
                    ) -> dict[str, Any]:
    """JSON-ready summary: count, chunks, bytes, schema, metadata, and counts per value of
    the scalar field ``group_by`` (``groups`` is None when the field is absent).

    Every chunk is checked against its hash; :class:`CorruptChunkError` names all bad ones.
    """
    dataset = open_dataset(path)
    grouped = group_by is not None and dataset.schema.get(group_by, {}).get("shape") == []
    problems, chunks = [], []
    for index in range(len(dataset.chunk_counts)):
        try:
            chunks.append(dataset._load_chunk(index, (group_by,) if grouped else ()))
        except CorruptChunkError as error:
            problems.extend(error.chunks)
    if problems:
        raise CorruptChunkError(dataset.path, problems, len(dataset))
    groups = None
    if grouped:
        values, counts = np.unique(np.concatenate([c[group_by] for c in chunks] or [[]]), return_counts=True)
        groups = {str(v): int(c) for v, c in zip(values, counts, strict=True)}
    return {
        "path": str(dataset.path), "count": len(dataset), "chunks": len(dataset.chunk_counts),
        "bytes": sum((dataset.path / c["file"]).stat().st_size for c in dataset._chunks),
        "schema": dataset.schema, "metadata": dataset.metadata,
        "group_by": group_by if groups is not None else None, "groups": groups,
    }
