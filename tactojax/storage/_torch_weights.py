"""Read PyTorch checkpoints as numpy arrays without torch and without running pickled code.

Three formats, chosen by the file's first bytes (not its suffix):

- **zip** (``torch.save`` since torch 1.6): a zip archive ``<name>/data.pkl`` (the pickled
  object; each storage is a *persistent id* ``("storage", StorageType, key, location,
  numel)``) and ``<name>/data/<key>`` (the storage's raw little-endian bytes; a
  ``<name>/byteorder`` record says ``big`` otherwise).
- **legacy** (``_use_new_zipfile_serialization=False`` and torch < 1.6): five pickles in a row
  (magic number, protocol 1001, system info, the object with persistent ids
  ``("storage", StorageType, key, location, numel, view_metadata)``, the sorted storage keys),
  then for each key an int64 element count and the storage's raw bytes.
- **safetensors**: an 8-byte little-endian header length, a JSON header ``{name: {"dtype",
  "shape", "data_offsets"}}``, then the raw bytes. This module reads it itself (about 25 lines)
  instead of importing the ``safetensors`` package: the format is three documented fields, so
  one code path with the same checks and error messages serves every install, and the test
  suite compares it with files written by the official package.

Pickles are read by :class:`_RestrictedUnpickler`, whose ``find_class`` returns numpy
rebuilders for an allow-list of globals (``collections.OrderedDict``, ``torch._utils``'s
tensor/parameter rebuilders, ``torch.*Storage`` types, ...) and raises
:class:`UnsafeCheckpointError` for anything else, so no callable named by the file ever runs.
"""

from __future__ import annotations

import collections
import io
import json
import math
import pickle
import struct
import zipfile
from pathlib import Path

import ml_dtypes
import numpy as np

_LEGACY_MAGIC = 0x1950A86A20F9469CFC6C
_LEGACY_PROTOCOL = 1001

_STORAGE_DTYPES = {
    "DoubleStorage": np.dtype(np.float64),
    "FloatStorage": np.dtype(np.float32),
    "HalfStorage": np.dtype(np.float16),
    "BFloat16Storage": np.dtype(ml_dtypes.bfloat16),
    "LongStorage": np.dtype(np.int64),
    "IntStorage": np.dtype(np.int32),
    "ShortStorage": np.dtype(np.int16),
    "CharStorage": np.dtype(np.int8),
    "ByteStorage": np.dtype(np.uint8),
    "BoolStorage": np.dtype(np.bool_),
    "ComplexFloatStorage": np.dtype(np.complex64),
    "ComplexDoubleStorage": np.dtype(np.complex128),
    "UntypedStorage": np.dtype(np.uint8),
}

_SAFETENSORS_DTYPES = {
    "F64": np.dtype("<f8"),
    "F32": np.dtype("<f4"),
    "F16": np.dtype("<f2"),
    "BF16": np.dtype(ml_dtypes.bfloat16),
    "I64": np.dtype("<i8"),
    "I32": np.dtype("<i4"),
    "I16": np.dtype("<i2"),
    "I8": np.dtype("i1"),
    "U64": np.dtype("<u8"),
    "U32": np.dtype("<u4"),
    "U16": np.dtype("<u2"),
    "U8": np.dtype("u1"),
    "BOOL": np.dtype(np.bool_),
    "F8_E4M3": np.dtype(ml_dtypes.float8_e4m3fn),
    "F8_E5M2": np.dtype(ml_dtypes.float8_e5m2),
}
_SAFETENSORS_MAX_HEADER = 100_000_000


class UnsafeCheckpointError(ValueError):
    """A checkpoint whose pickle names a global outside the allow-list (it was not executed)."""


class CorruptTorchCheckpointError(ValueError):
    """A PyTorch/safetensors checkpoint that is truncated, malformed or of an unsupported kind."""


class _FromPickle:
    """Base of the objects a pickle can reach: the stream's BUILD opcode may not modify them."""

    __slots__ = ()

    def __setstate__(self, state):
        raise UnsafeCheckpointError(f"pickle tries to modify a {type(self).__name__} (BUILD opcode)")


class _Storage(_FromPickle):
    """A flat typed storage: ``data`` is filled when its bytes are read."""

    __slots__ = ("key", "dtype", "numel", "data")

    def __init__(self, key: str, dtype: np.dtype, numel: int):
        if numel < 0:
            raise CorruptTorchCheckpointError(f"storage {key!r} has {numel} elements")
        self.key, self.dtype, self.numel = key, dtype, numel
        self.data: np.ndarray | None = None


class _LazyTensor(_FromPickle):
    """A strided view of a :class:`_Storage`, materialised once every storage is read."""

    __slots__ = ("storage", "offset", "size", "stride")

    def __init__(self, storage, offset, size, stride):
        if not isinstance(storage, _Storage):
            raise CorruptTorchCheckpointError(f"tensor rebuilt from {type(storage).__name__}, not a storage")
        self.storage, self.offset = storage, int(offset)
        self.size, self.stride = tuple(int(n) for n in size), tuple(int(s) for s in stride)
        if len(self.size) != len(self.stride) or self.offset < 0 or min(self.size + self.stride, default=0) < 0:
            raise CorruptTorchCheckpointError(f"invalid tensor layout size={self.size} stride={self.stride}")
        if 0 not in self.size:
            last = self.offset + sum((n - 1) * s for n, s in zip(self.size, self.stride, strict=True))
            if last >= storage.numel:
                raise CorruptTorchCheckpointError(
                    f"tensor of size {self.size} at offset {self.offset} overruns its storage of {storage.numel}"
                )

    def materialise(self) -> np.ndarray:
        """A new, writable, native-byte-order array (never a view of the file's bytes)."""
        data = self.storage.data
        if data is None or data.size != self.storage.numel:
            raise CorruptTorchCheckpointError(f"storage {self.storage.key!r} has no data")
        native = data.dtype.newbyteorder("=")
        if 0 in self.size:
            return np.zeros(self.size, dtype=native)
        view = np.lib.stride_tricks.as_strided(
            data[self.offset :], shape=self.size, strides=[s * data.itemsize for s in self.stride], writeable=False
        )
        return np.array(view, dtype=native)


class _Allowed(_FromPickle):
    """An allow-listed callable handed to the unpickler."""

    __slots__ = ("function", "name")

    def __init__(self, function, name: str):
        self.function, self.name = function, name

    def __call__(self, *args):
        return self.function(*args)


class _TensorType(_FromPickle):
    """Stands for ``torch.Tensor`` / ``torch.nn.Parameter`` inside ``_rebuild_from_type_v2``."""

    __slots__ = ()


class _StorageType(_FromPickle):
    """Stands for a ``torch.*Storage`` class in a persistent id."""

    __slots__ = ("dtype",)

    def __init__(self, dtype: np.dtype):
        self.dtype = dtype


def _rebuild_tensor(storage, storage_offset, size, stride, *_ignored):
    """``torch._utils._rebuild_tensor(_v2)``: requires_grad, hooks and metadata are dropped."""
    return _LazyTensor(storage, storage_offset, size, stride)


def _rebuild_parameter(data, *_ignored):
    """``torch._utils._rebuild_parameter(_with_state)``: a parameter is its data."""
    return data


def _rebuild_from_type_v2(func, new_type, args, state):
    """``torch._tensor._rebuild_from_type_v2`` for plain tensors and parameters only."""
    allowed = isinstance(func, _Allowed) and func.function in (_rebuild_tensor, _rebuild_parameter)
    if not allowed or not isinstance(new_type, _TensorType):
        raise UnsafeCheckpointError("tensor subclass rebuilt with a function outside the allow-list")
    return func(*args)


def _codecs_encode(text, encoding="utf-8"):
    """``_codecs.encode``: how protocol-2 pickles store ``bytes``."""
    return str(text).encode(str(encoding))


_ALLOWED_GLOBALS: dict[tuple[str, str], object] = {
    ("collections", "OrderedDict"): collections.OrderedDict,
    ("torch", "Size"): tuple,
    ("builtins", "set"): set,
    ("builtins", "frozenset"): frozenset,
    ("builtins", "complex"): complex,
    ("torch", "Tensor"): _TensorType(),
    ("torch._tensor", "Tensor"): _TensorType(),
    ("torch.nn.parameter", "Parameter"): _TensorType(),
}
for _module, _name, _function in [
    ("torch._utils", "_rebuild_tensor", _rebuild_tensor),
    ("torch._utils", "_rebuild_tensor_v2", _rebuild_tensor),
    ("torch._utils", "_rebuild_parameter", _rebuild_parameter),
    ("torch._utils", "_rebuild_parameter_with_state", _rebuild_parameter),
    ("torch._tensor", "_rebuild_from_type_v2", _rebuild_from_type_v2),
    ("_codecs", "encode", _codecs_encode),
]:
    _ALLOWED_GLOBALS[(_module, _name)] = _Allowed(_function, f"{_module}.{_name}")
for _module in ("torch", "torch.storage", "torch.cuda"):
    for _name, _dtype in _STORAGE_DTYPES.items():
        _ALLOWED_GLOBALS[(_module, _name)] = _StorageType(_dtype)


class _RestrictedUnpickler(pickle.Unpickler):
    """Unpickler that resolves only allow-listed globals and torch storage persistent ids.

    Args:
        file: binary file positioned at a pickle.
        read_storage: ``(key, dtype, numel) -> np.ndarray | None``; the storage's bytes now (zip
            format) or ``None`` when they follow the pickle (legacy format).
    """

    def __init__(self, file, read_storage):
        super().__init__(file)
        self._read_storage = read_storage
        self.storages: dict[str, _Storage] = {}

    def find_class(self, module: str, name: str):
        try:
            return _ALLOWED_GLOBALS[(module, name)]
        except KeyError:
            raise UnsafeCheckpointError(
                f"refusing to load global {module}.{name}: only tensors, storages and plain containers "
                "are allowed (re-save the model's state_dict(), or convert it to .safetensors)"
            ) from None

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and len(pid) in (5, 6) and pid[0] in ("storage", b"storage")):
            raise CorruptTorchCheckpointError(f"unsupported persistent id {str(pid)[:80]}")
        if self._read_storage is None:
            raise CorruptTorchCheckpointError("storage reference outside the checkpoint's object")
        storage_type, key, numel = pid[1], str(pid[2]), pid[4]
        if not isinstance(storage_type, _StorageType) or not isinstance(numel, int):
            raise CorruptTorchCheckpointError(f"storage {key!r} has no storage type or size")
        if len(pid) == 6 and pid[5] is not None:
            raise CorruptTorchCheckpointError("storage views (torch < 0.4 checkpoints) are not supported")
        if key not in self.storages:
            storage = _Storage(key, storage_type.dtype, numel)
            storage.data = self._read_storage(key, storage.dtype, storage.numel)
            self.storages[key] = storage
        return self.storages[key]


def _materialise(obj):
    """Replace every :class:`_LazyTensor` in nested dicts/lists/tuples by its numpy array."""
    if isinstance(obj, _LazyTensor):
        return obj.materialise()
    if isinstance(obj, dict):
        return {key: _materialise(value) for key, value in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_materialise(value) for value in obj)
    return obj


def _read_zip(raw: bytes) -> object:
    with zipfile.ZipFile(io.BytesIO(raw)) as archive:
        names = set(archive.namelist())
        pickles = [name for name in names if name.endswith("/data.pkl") and name.count("/") == 1]
        if len(pickles) != 1:
            raise CorruptTorchCheckpointError("zip archive without exactly one <name>/data.pkl: not a torch.save file")
        prefix = pickles[0][: -len("data.pkl")]
        byteorder = "little"
        if prefix + "byteorder" in names:
            byteorder = archive.read(prefix + "byteorder").decode().strip()
        swap = byteorder != "little"

        def read_storage(key, dtype, numel):
            record = f"{prefix}data/{key}"
            if record not in names:
                raise CorruptTorchCheckpointError(f"missing storage record {record}")
            data = archive.read(record)
            if len(data) < numel * dtype.itemsize:
                raise CorruptTorchCheckpointError(f"storage {key}: {len(data)} bytes, not {numel * dtype.itemsize}")
            return np.frombuffer(data, dtype.newbyteorder(">" if swap else "<"), count=numel)

        with archive.open(pickles[0]) as stream:
            return _materialise(_RestrictedUnpickler(io.BytesIO(stream.read()), read_storage).load())


def _read_legacy(raw: bytes) -> object:
    stream = io.BytesIO(raw)
    header = [_RestrictedUnpickler(stream, None).load() for _ in range(3)]
    if header[0] != _LEGACY_MAGIC or header[1] != _LEGACY_PROTOCOL:
        raise CorruptTorchCheckpointError("not a PyTorch checkpoint (bad magic number or protocol)")
    little = header[2].get("little_endian", True) if isinstance(header[2], dict) else True
    unpickler = _RestrictedUnpickler(stream, lambda key, dtype, numel: None)
    result = unpickler.load()
    keys = _RestrictedUnpickler(stream, None).load()
    if not isinstance(keys, list) or set(map(str, keys)) != set(unpickler.storages):
        raise CorruptTorchCheckpointError("storage key list does not match the pickled storages")
    for key in map(str, keys):
        storage = unpickler.storages[key]
        size = stream.read(8)
        if len(size) < 8:
            raise CorruptTorchCheckpointError(f"truncated before storage {key}")
        numel = struct.unpack("<q" if little else ">q", size)[0]
        if numel != storage.numel:
            raise CorruptTorchCheckpointError(f"storage {key} has {numel} elements, the pickle says {storage.numel}")
        data = stream.read(numel * storage.dtype.itemsize)
        if len(data) < numel * storage.dtype.itemsize:
            raise CorruptTorchCheckpointError(f"truncated inside storage {key}")
        storage.data = np.frombuffer(data, storage.dtype.newbyteorder("<" if little else ">"))
    return _materialise(result)


def _read_safetensors(raw: bytes) -> dict[str, np.ndarray]:
    (header_size,) = struct.unpack("<Q", raw[:8])
    if header_size > min(_SAFETENSORS_MAX_HEADER, len(raw) - 8):
        raise CorruptTorchCheckpointError(f"safetensors header of {header_size} bytes is truncated or too large")
    header = json.loads(raw[8 : 8 + header_size])
    buffer = memoryview(raw)[8 + header_size :]
    arrays = {}
    for name, entry in header.items():
        if name == "__metadata__":
            continue
        try:
            dtype, shape, (begin, end) = _SAFETENSORS_DTYPES[entry["dtype"]], tuple(entry["shape"]), entry["data_offsets"]
        except (KeyError, TypeError, ValueError):
            raise CorruptTorchCheckpointError(f"malformed or unsupported safetensors entry {name!r}: {entry}") from None
        if not 0 <= begin <= end <= len(buffer) or end - begin != math.prod(shape) * dtype.itemsize:
            raise CorruptTorchCheckpointError(f"tensor {name!r} at bytes {begin}..{end} does not fit (file truncated?)")
        arrays[name] = np.frombuffer(buffer[begin:end], dtype).reshape(shape).astype(dtype.newbyteorder("="))
    return arrays


def _flatten_arrays(obj, prefix: str = "") -> dict[str, np.ndarray]:
    """Arrays of nested dicts under dotted keys; non-array leaves (epoch counters, ...) are dropped."""
    if isinstance(obj, np.ndarray):
        return {prefix: obj}
    if isinstance(obj, dict):
        flat = {}
        for key, value in obj.items():
            flat.update(_flatten_arrays(value, f"{prefix}.{key}" if prefix else str(key)))
        return flat
    return {}


def load_torch_state_dict(path: str | Path) -> dict[str, np.ndarray]:
    """Read a PyTorch state dict (zip or legacy ``.pth``/``.pt``, or ``.safetensors``) as numpy arrays.

    No pickled code runs and torch is not imported. A checkpoint that wraps its weights
    (``{"state_dict": ...}``, ``{"model": ...}``) is unwrapped; other nested dicts are flattened
    with dotted keys; non-tensor entries are dropped.

    Args:
        path: checkpoint file.

    Returns:
        ``{name: array}`` with the stored shapes and dtypes (torch's layout, e.g. convolution
        weights ``(out, in, kh, kw)``); bfloat16 becomes ``ml_dtypes.bfloat16``.

    Raises:
        FileNotFoundError: no such file.
        UnsafeCheckpointError: the pickle names a global outside the allow-list (a pickled
            module, an optimizer state, a TorchScript archive, arbitrary code).
        CorruptTorchCheckpointError: truncated, malformed or unsupported file; names the file.
    """
    path = Path(path)
    raw = path.read_bytes()
    try:
        if raw.startswith(b"PK"):
            obj = _read_zip(raw)
        elif raw.startswith(b"\x80"):
            obj = _read_legacy(raw)
        elif raw[8:9] == b"{":
            return _read_safetensors(raw)
        else:
            raise CorruptTorchCheckpointError(
                "neither a torch.save file (zip or legacy) nor safetensors (torch < 0.4 tar files are not supported)"
            )
    except UnsafeCheckpointError as error:
        raise UnsafeCheckpointError(f"{path}: {error}") from None
    except CorruptTorchCheckpointError as error:
        raise CorruptTorchCheckpointError(f"{path}: {error}") from None
    except (pickle.UnpicklingError, EOFError, zipfile.BadZipFile, NotImplementedError, ValueError, TypeError,
            AttributeError, IndexError, KeyError, struct.error, OverflowError, MemoryError) as error:
        # MemoryError: a corrupt length field made the unpickler allocate a huge buffer.
        message = f"{path}: truncated or corrupt checkpoint ({type(error).__name__}: {error})"
        raise CorruptTorchCheckpointError(message) from None
    for wrapper in ("state_dict", "model", "model_state_dict"):
        if isinstance(obj, dict) and isinstance(obj.get(wrapper), dict):
            obj = obj[wrapper]
            break
    arrays = _flatten_arrays(obj)
    if not arrays:
        raise CorruptTorchCheckpointError(f"{path}: checkpoint holds no tensors")
    return arrays
