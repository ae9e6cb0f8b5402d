"""The checkpoint container: a msgpack map with a ``format`` name and a ``version``, no pickle.

Shape models (``tactojax.io.save_shape_model``) and encoders (``tactojax.io.save_encoder``) are
written in it; this module reads the container and checks its format and version, the stage
that owns the checkpoint turns the payload into its model.
"""

from __future__ import annotations

from pathlib import Path

from flax import serialization


class CorruptCheckpointError(ValueError):
    """A checkpoint file that cannot be read or is not a tactojax checkpoint."""


def read_checkpoint_payload(path, expected_format: str, readable_versions, *, kind: str = "checkpoint") -> dict:
    """The msgpack payload of a tactojax checkpoint, checked for its format and version.

    Shared by the shape-model and encoder checkpoints. ``kind`` names the file in errors
    (e.g. ``"encoder checkpoint"``).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no {kind} at {path}")
    try:
        payload = serialization.msgpack_restore(path.read_bytes())
    except Exception as error:  # msgpack raises several unrelated types
        raise CorruptCheckpointError(f"{path} is not a readable {kind} ({error})") from None
    if not isinstance(payload, dict) or payload.get("format") != expected_format:
        raise CorruptCheckpointError(f"{path} is not a {expected_format} file")
    if payload.get("version") not in readable_versions:
        raise CorruptCheckpointError(
            f"{path}: unsupported {kind.removesuffix('checkpoint')}version {payload.get('version')}")
    return payload


BUNDLED_DIR = Path(__file__).resolve().parent.parent / "checkpoints"
"""Checkpoints shipped inside the package (each reproduced by the command in its metadata)."""
