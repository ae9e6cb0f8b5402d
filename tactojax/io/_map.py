"""Tactile maps on disk, and their export as a PLY point cloud.

Map format (compressed ``.npz``, read with ``allow_pickle=False``, written atomically): a zip of numpy
arrays, one per :class:`~tactojax.mapping.TactileMap` field, plus ``header``, a JSON string:
``{"format": "tactojax-tactile-map", "version": 1, "object_id", "mm_per_px", "sensor",
"metadata": {...}}``. Arrays: ``images`` (K, H, W, 3) uint8; ``heightmaps`` (K, H, W) float32
mm; ``masks`` (K, H, W) bool; ``points``/``normals`` (K, P, 3) float32, sensor frame;
``valid`` (K, P) bool; ``T_object_sensor`` (K, 7) float32 (quaternion wxyz, then xyz in mm);
``openings`` (K,) float32 mm; ``features`` (K, F) float32; ``imprint_valid`` (K,) bool.

PLY export: binary little-endian vertices ``x y z nx ny nz`` (float32, mm, object frame).
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.storage._atomic import atomic_open
from tactojax.storage._dataset import open_dataset
from tactojax.mapping import TactileMap, stitched_point_cloud

MAP_FORMAT = "tactojax-tactile-map"
MAP_VERSION = 1

_DTYPES = {
    "images": np.uint8, "heightmaps": np.float32, "masks": np.bool_, "points": np.float32,
    "normals": np.float32, "valid": np.bool_, "T_object_sensor": np.float32,
    "openings": np.float32, "features": np.float32, "imprint_valid": np.bool_,
}


class CorruptMapError(ValueError):
    """A file that is not a readable tactojax tactile map."""


def save_tactile_map(path, tactile_map: TactileMap, *, metadata: dict | None = None) -> Path:
    """Write a map atomically (see the module docstring for the format).

    Args:
        path: destination ``.npz`` file.
        tactile_map: the map.
        metadata: JSON-serialisable notes kept with it (source data, model, settings).
    """
    header = {"format": MAP_FORMAT, "version": MAP_VERSION, "object_id": tactile_map.object_id,
              "mm_per_px": tactile_map.mm_per_px, "sensor": tactile_map.sensor,
              "metadata": metadata or {}}
    arrays = {name: np.asarray(getattr(tactile_map, name), dtype) for name, dtype in _DTYPES.items()
              if name != "T_object_sensor"}
    arrays["T_object_sensor"] = np.asarray(tactile_map.T_object_sensor.wxyz_xyz, np.float32)
    path = Path(path)
    with atomic_open(path, "wb") as handle:
        np.savez_compressed(handle, header=np.array(json.dumps(header)), **arrays)
    return path


def _read_npz(path: Path, *, arrays: bool = True) -> tuple[dict, dict[str, np.ndarray]]:
    """(header, arrays) of a map file; ``arrays=False`` reads only the header (no decompression
    of the images and heightmaps)."""
    if not path.is_file():
        raise FileNotFoundError(f"no tactile map at {path}")
    try:
        with np.load(path, allow_pickle=False) as npz:
            header = json.loads(str(npz["header"]))
            contents = {name: npz[name] for name in npz.files if name != "header"} if arrays else {}
    except (zipfile.BadZipFile, OSError, ValueError, KeyError, EOFError) as error:
        raise CorruptMapError(f"{path} is not a readable tactile map ({error})") from None
    if not isinstance(header, dict) or header.get("format") != MAP_FORMAT:
        raise CorruptMapError(f"{path} is not a {MAP_FORMAT} file")
    if header.get("version") != MAP_VERSION:
        raise CorruptMapError(f"{path}: unsupported tactile map version {header.get('version')}")
    return header, contents


def _check_arrays(path: Path, arrays: dict[str, np.ndarray]) -> None:
    missing = sorted(set(_DTYPES) - set(arrays))
    if missing:
        raise CorruptMapError(f"{path}: missing arrays {missing}")
    wrong_type = [name for name, dtype in _DTYPES.items() if arrays[name].dtype != dtype]
    if wrong_type:
        raise CorruptMapError(f"{path}: wrong data type for {wrong_type}")
    if arrays["heightmaps"].ndim != 3 or arrays["points"].ndim != 3 or arrays["features"].ndim != 2:
        raise CorruptMapError(f"{path}: heightmaps, points or features have the wrong rank")
    count, height, width = arrays["heightmaps"].shape
    points, features = arrays["points"].shape[1], arrays["features"].shape[1]
    expected = {
        "images": (count, height, width, 3), "masks": (count, height, width),
        "points": (count, points, 3), "normals": (count, points, 3), "valid": (count, points),
        "T_object_sensor": (count, 7), "openings": (count,), "features": (count, features),
        "imprint_valid": (count,),
    }
    wrong = [f"{name} {arrays[name].shape} (expected {shape})" for name, shape in expected.items()
             if arrays[name].shape != shape]
    if wrong:
        raise CorruptMapError(f"{path}: array shapes disagree: {'; '.join(wrong)}")


def load_tactile_map(path) -> TactileMap:
    """Read a map written by :func:`save_tactile_map`; clear errors for anything else."""
    path = Path(path)
    header, arrays = _read_npz(path)
    _check_arrays(path, arrays)
    poses = arrays.pop("T_object_sensor")
    return TactileMap(**{name: jnp.asarray(value) for name, value in arrays.items()},
                      T_object_sensor=jaxlie.SE3(jnp.asarray(poses)),
                      object_id=str(header["object_id"]), mm_per_px=float(header["mm_per_px"]),
                      sensor=str(header.get("sensor", "")))


def load_localization_map(path, *, encoder_name: str | None = None, progress: bool = False):
    """A map file as localization reads it (:class:`~tactojax.localize.LocalizationMap`: its
    imprints with their retrieval features, its surface, the object's symmetries), with the
    belief calibration its header stores (``tactojax calibrate-belief``; uncalibrated without one).

    Args:
        path: a map written by :func:`save_tactile_map` (``tactojax map``).
        encoder_name: the encoder of the retrieval features, when not the default. The features
            the map stores are used when they come from it (``calibrate-belief`` stores them);
            otherwise the map's images are encoded now. A calibration fit with another encoder
            is not used.
        progress: show a progress bar while encoding.
    """
    from tactojax.features import encode_images
    from tactojax.io._encoder import DEFAULT_ENCODER, resolve_encoder
    from tactojax.localize import LocalizationMap, calibration_from_json

    encoder_name = encoder_name or DEFAULT_ENCODER
    tactile_map = load_tactile_map(path)
    fit = tactile_map_metadata(path).get("metadata", {}).get("belief_calibration")
    usable = fit is not None and fit.get("encoder") == encoder_name
    if tactile_map.features.shape[1] == 0 or not usable:  # features of unknown origin: encode them
        encoder = resolve_encoder(encoder_name)
        tactile_map = tactile_map.with_features(encode_images(encoder, tactile_map.images, progress=progress))
    return LocalizationMap.from_tactile_map(tactile_map, calibration=calibration_from_json(fit) if usable else None)


def tactile_map_metadata(path) -> dict:
    """The header of a map file (object, pitch, sensor and its ``metadata`` dict)."""
    header, _ = _read_npz(Path(path), arrays=False)
    return header


def export_ply(path, tactile_map: TactileMap, *, voxel_mm: float = 0.5) -> int:
    """Write the map's stitched point cloud (object frame, mm) as a binary PLY, atomically.

    Args:
        path: destination ``.ply``.
        tactile_map: the map.
        voxel_mm: voxel edge for downsampling, mm (0: every point).

    Returns:
        The number of points written.
    """
    points, normals = stitched_point_cloud(tactile_map, voxel_mm=voxel_mm)
    vertices = np.concatenate([points, normals], axis=1).astype("<f4")
    header = "\n".join([
        "ply", "format binary_little_endian 1.0",
        f"comment tactojax tactile map of {tactile_map.object_id}, mm, object frame",
        f"element vertex {len(vertices)}",
        *[f"property float {name}" for name in ("x", "y", "z", "nx", "ny", "nz")],
        "end_header",
    ]) + "\n"
    with atomic_open(Path(path), "wb") as handle:
        handle.write(header.encode("ascii"))
        handle.write(vertices.tobytes())
    return len(vertices)


def read_grasps(path, *, object_id: str | None = None) -> dict:
    """The grasps of one object from a dataset, as map building needs them.

    Args:
        path: dataset directory (mapping protocol, or a real recording).
        object_id: which object (required when the dataset holds several).

    Returns:
        The object's records in dataset order (``"index"`` holds their record numbers, to read
        other fields such as a simulator's ground truth with ``open_dataset(path).read``):
        ``{"object_id", "index" (K,), "images" (K, H, W, 3) uint8, "T_world_gripper" SE3 (K,), "openings" (K,)
        mm, "T_world_object" SE3 (K,) or None (a recording without it: object fixed in the
        world), "mm_per_px", "sensor"}``.
    """
    dataset = open_dataset(path)
    needed = ["image", "T_world_gripper", "opening_mm", "object_id"]
    missing = [name for name in needed if name not in dataset.fields]
    if missing:
        raise ValueError(f"dataset {path} has no {', '.join(missing)}: not a grasp dataset")
    objects = dataset.read(["object_id"])["object_id"].astype(str)
    names = sorted(set(objects))
    if object_id is None:
        if len(names) != 1:
            raise ValueError(f"dataset {path} holds several objects {names}: choose one")
        object_id = names[0]
    if object_id not in names:
        raise ValueError(f"object {object_id!r} is not in dataset {path} (have {names})")
    index = np.flatnonzero(objects == object_id)
    if "finger" in dataset.fields and np.any(dataset.read(["finger"], index)["finger"] != 0):
        raise ValueError(f"dataset {path} holds second-finger imprints (finger 1, a sensor on the opposite jaw, "
                         "from --fingers 2): maps are built from the gripper's sensor jaw; read it as a test set "
                         "(read_test_grasps, eval-localization --test) instead")
    fields = needed + (["T_world_object"] if "T_world_object" in dataset.fields else [])
    data = dataset.read(fields, index)
    sensor = dataset.metadata.get("sensor", {})
    if sensor.get("mm_per_px") is None:
        raise ValueError(f"dataset {path} does not record mm_per_px in its sensor metadata")
    return {
        "object_id": object_id, "index": index, "images": data["image"],
        "T_world_gripper": jaxlie.SE3(jnp.asarray(data["T_world_gripper"], jnp.float32)),
        "openings": jnp.asarray(data["opening_mm"], jnp.float32),
        "T_world_object": (jaxlie.SE3(jnp.asarray(data["T_world_object"], jnp.float32))
                           if "T_world_object" in data else None),
        "mm_per_px": float(sensor["mm_per_px"]), "sensor": sensor.get("name", ""),
    }
