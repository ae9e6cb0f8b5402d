"""Tactile maps on disk, and their export as a PLY point cloud.

Map format (compressed ``.npz``, read with ``allow_pickle=False``, written atomically): a zip of numpy
arrays plus ``header``, a JSON string: ``{"format": "tactojax-tactile-map", "version": 2,
"object_id", "mm_per_px", "sensor", "metadata": {...}}``, and ``"symmetry"`` (the object's
symmetry group, :meth:`~tactojax.objects.ObjectSymmetry.to_json`) when the map recorded one.
Version 2 (compact) arrays, one per stored
:class:`~tactojax.mapping.TactileMap` field: ``packed_heightmaps`` (K, H, W) float16 mm with the
contact mask in the sign bit; ``point_pixels`` (K, P) uint16 (int32 past 65536 pixels), the
contact points' pixels (row * W + col); ``valid`` (K, P) bool; ``T_object_sensor`` (K, 7) float32
(quaternion wxyz, then xyz in mm); ``openings`` (K,) float32 mm; ``features`` (K, F) float32;
``imprint_valid`` (K,) bool; only when kept, ``images`` (K, H, W, 3) uint8; and, in maps
written since 2026-11-29, ``surface_pixels`` (K, S) uint16/int32 with ``surface_valid`` (K, S)
bool, the pixels of the whole predicted contact mask that the surface is built from (older maps
build it from the contact points). The metadata's ``features_encoder`` names the encoder of the
stored features.

The map's surface (:class:`~tactojax.localize.MapSurface`, what localization reads; optional, maps
written before it have none): ``surface_blocks`` (N, 5, 5, 5) float32 signed distances, mm (NaN:
unknown), ``surface_block_index`` (I, J, K) int32, and the header's ``"surface"``:
``{"origin_mm": [x, y, z], "settings": {"pitch_mm", "reach_mm", "margin_mm", "min_depth_mm"}}``.
It is built from the stored imprints when the map is saved, so that loading a map for
localization reads it instead of building it again (1-4 s a map).

Version 1 (read, converted on loading): ``images``; ``heightmaps`` (K, H, W) float32; ``masks``
(K, H, W) bool; ``points``/``normals`` (K, P, 3) float32, sensor frame (points on the pixel grid);
and ``valid``, ``T_object_sensor``, ``openings``, ``features``, ``imprint_valid`` as in version 2.

PLY export: binary little-endian vertices ``x y z nx ny nz`` (float32, mm, object frame).
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.localize import MapSurface, SurfaceSettings, build_map_surface
from tactojax.mapping import TactileMap, pack_heightmaps, points_to_pixels, stitched_point_cloud
from tactojax.objects import ObjectSymmetry
from tactojax.simulate import symmetry_key
from tactojax.storage._atomic import atomic_open
from tactojax.storage._dataset import open_dataset

MAP_FORMAT = "tactojax-tactile-map"
MAP_VERSION = 2
"""The version :func:`save_tactile_map` writes; :func:`load_tactile_map` reads 1 and 2."""

_COMMON = {"valid": np.bool_, "T_object_sensor": np.float32, "openings": np.float32, "features": np.float32,
           "imprint_valid": np.bool_}
_DTYPES = {
    1: {"images": np.uint8, "heightmaps": np.float32, "masks": np.bool_, "points": np.float32,
        "normals": np.float32, **_COMMON},
    2: {"packed_heightmaps": np.float16, "point_pixels": [np.uint16, np.int32], **_COMMON},
}
_OPTIONAL = {"images": np.uint8}  # version 2
_SURFACE_PIXELS = {"surface_pixels": [np.uint16, np.int32], "surface_valid": np.bool_}  # version 2, both or neither
_SURFACE = {"surface_blocks": np.float32, "surface_block_index": np.int32}


class CorruptMapError(ValueError):
    """A file that is not a readable tactojax tactile map."""


def save_tactile_map(path, tactile_map: TactileMap, *, metadata: dict | None = None, surface: bool = True) -> Path:
    """Write a map atomically in the compact format (see the module docstring), with its images
    when it holds them.

    Args:
        path: destination ``.npz`` file.
        tactile_map: the map.
        metadata: JSON-serialisable notes kept with it (source data, model, settings).
        surface: also store the map's surface (built now with the default
            :class:`~tactojax.localize.SurfaceSettings`, 1-4 s a map on the host), which
            :func:`load_localization_map` then reads instead of building it.
    """
    header = {"format": MAP_FORMAT, "version": MAP_VERSION, "object_id": tactile_map.object_id,
              "mm_per_px": tactile_map.mm_per_px, "sensor": tactile_map.sensor,
              "metadata": metadata or {}}
    if tactile_map.symmetry is not None:
        header["symmetry"] = tactile_map.symmetry.to_json()
    arrays = {name: np.asarray(getattr(tactile_map, name)) for name in _DTYPES[MAP_VERSION]
              if name != "T_object_sensor"}
    arrays["T_object_sensor"] = np.asarray(tactile_map.T_object_sensor.wxyz_xyz, np.float32)
    if tactile_map.surface_pixels is not None:
        arrays.update({name: np.asarray(getattr(tactile_map, name)) for name in _SURFACE_PIXELS})
    if tactile_map.images is not None:
        arrays["images"] = np.asarray(tactile_map.images, np.uint8)
    if surface:
        settings = SurfaceSettings()
        header["surface"], surface_arrays = _surface_entry(build_map_surface(tactile_map, settings), settings)
        arrays.update(surface_arrays)
    path = Path(path)
    with atomic_open(path, "wb") as handle:
        np.savez_compressed(handle, header=np.array(json.dumps(header)), **arrays)
    return path


def _read_npz(path: Path, *, arrays: bool = True, images: bool = True,
              surface: bool = False) -> tuple[dict, dict[str, np.ndarray]]:
    """(header, arrays) of a map file; ``arrays=False`` reads only the header (no decompression
    of the images and heightmaps), ``images=False`` all but the images, ``surface=True`` only
    the surface's arrays (without, all but those)."""
    if not path.is_file():
        raise FileNotFoundError(f"no tactile map at {path}")
    try:
        with np.load(path, allow_pickle=False) as npz:
            header = json.loads(str(npz["header"]))
            wanted = [name for name in npz.files if name != "header" and (images or name != "images")
                      and (name in _SURFACE) == surface]
            contents = {name: npz[name] for name in wanted} if arrays else {}
    except (zipfile.BadZipFile, OSError, ValueError, KeyError, EOFError) as error:
        raise CorruptMapError(f"{path} is not a readable tactile map ({error})") from None
    if not isinstance(header, dict) or header.get("format") != MAP_FORMAT:
        raise CorruptMapError(f"{path} is not a {MAP_FORMAT} file")
    if header.get("version") not in _DTYPES:
        raise CorruptMapError(f"{path}: unsupported tactile map version {header.get('version')}")
    return header, contents


def _check_arrays(path: Path, version: int, arrays: dict[str, np.ndarray]) -> None:
    dtypes = (_DTYPES[version] | (_OPTIONAL if "images" in arrays else {})
              | (_SURFACE_PIXELS if set(_SURFACE_PIXELS) & set(arrays) else {}))
    missing = sorted(set(dtypes) - set(arrays) - {"images"})
    if missing:
        raise CorruptMapError(f"{path}: missing arrays {missing}")
    present = [name for name in dtypes if name in arrays]
    wrong_type = [name for name in present if arrays[name].dtype not in np.atleast_1d(dtypes[name])]
    if wrong_type:
        raise CorruptMapError(f"{path}: wrong data type for {wrong_type}")
    heights, points = ("heightmaps", "points") if version == 1 else ("packed_heightmaps", "point_pixels")
    if arrays[heights].ndim != 3 or arrays[points].ndim != 3 - (version == 2) or arrays["features"].ndim != 2:
        raise CorruptMapError(f"{path}: heightmaps, points or features have the wrong rank")
    count, height, width = arrays[heights].shape
    points, features = arrays[points].shape[1], arrays["features"].shape[1]
    expected = {
        "images": (count, height, width, 3), "masks": (count, height, width),
        "points": (count, points, 3), "normals": (count, points, 3), "point_pixels": (count, points),
        "valid": (count, points), "T_object_sensor": (count, 7), "openings": (count,),
        "features": (count, features), "imprint_valid": (count,),
    }
    if "surface_pixels" in arrays:
        expected["surface_valid"] = arrays["surface_pixels"].shape
        if arrays["surface_pixels"].ndim != 2 or len(arrays["surface_pixels"]) != count:
            raise CorruptMapError(f"{path}: surface_pixels {arrays['surface_pixels'].shape} is not ({count}, S)")
    wrong = [f"{name} {arrays[name].shape} (expected {shape})" for name, shape in expected.items()
             if name in arrays and arrays[name].shape != shape]
    if wrong:
        raise CorruptMapError(f"{path}: array shapes disagree: {'; '.join(wrong)}")
    for name in ("point_pixels", "surface_pixels"):
        if version == 2 and name in arrays and arrays[name].size and int(arrays[name].max()) >= height * width:
            raise CorruptMapError(f"{path}: {name} index past the {height} x {width} image")


def _compact_arrays(path: Path, header: dict, arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A version-1 file's arrays in the version-2 layout (heightmaps packed, points as pixels)."""
    heightmaps, masks, points = arrays.pop("heightmaps"), arrays.pop("masks"), arrays.pop("points")
    del arrays["normals"]  # recomputed from the heightmaps at the points' pixels
    try:
        pixels = points_to_pixels(points, *heightmaps.shape[1:], float(header["mm_per_px"]))
    except ValueError as error:
        raise CorruptMapError(f"{path}: {error}") from None
    return {**arrays, "packed_heightmaps": np.asarray(pack_heightmaps(heightmaps, masks)), "point_pixels": pixels}


def load_tactile_map(path, *, images: bool = False) -> TactileMap:
    """Read a map written by :func:`save_tactile_map` (format version 2, or 1: converted to the
    compact layout on loading); clear errors for anything else.

    Args:
        path: the ``.npz`` file.
        images: also read the tactile images, when the file keeps them (only encoding features
            anew needs them; without, the map's ``images`` is None).
    """
    path = Path(path)
    header, arrays = _read_npz(path, images=images)
    version = int(header["version"])
    _check_arrays(path, version, arrays)
    if version == 1:
        arrays = _compact_arrays(path, header, arrays)
    poses = arrays.pop("T_object_sensor")
    stored_images = arrays.pop("images", None)
    return TactileMap(**{name: jnp.asarray(value) for name, value in arrays.items()},
                      images=None if stored_images is None else jnp.asarray(stored_images),
                      T_object_sensor=jaxlie.SE3(jnp.asarray(poses)),
                      object_id=str(header["object_id"]), mm_per_px=float(header["mm_per_px"]),
                      sensor=str(header.get("sensor", "")),
                      symmetry=ObjectSymmetry.from_json(header["symmetry"]) if "symmetry" in header else None)


def _settings_json(settings: SurfaceSettings) -> dict[str, float]:
    """The header's record of the settings a stored surface was built with."""
    return {name: float(getattr(settings, name)) for name in SurfaceSettings.__dataclass_fields__}


def _surface_entry(surface: MapSurface, settings: SurfaceSettings) -> tuple[dict, dict[str, np.ndarray]]:
    """The header entry and arrays that store a map's surface, built with ``settings`` (see the
    module docstring)."""
    if surface.grid is not None:
        raise ValueError("a surface within a StackedMaps is not a map's own: store StackedMaps.map(m)'s")
    entry = {"origin_mm": np.asarray(surface.origin, np.float64).tolist(), "settings": _settings_json(settings)}
    return entry, {"surface_blocks": np.asarray(surface.blocks, np.float32),
                   "surface_block_index": np.asarray(surface.block_index, np.int32)}


def stored_surface(path, settings: SurfaceSettings = SurfaceSettings()) -> MapSurface | None:
    """The surface a map file stores (:func:`save_tactile_map`), or None when it stores none or
    one built with other settings than ``settings`` (then build it:
    :func:`~tactojax.localize.build_map_surface`).

    Raises:
        CorruptMapError: the stored surface's arrays are missing, of the wrong type or disagree.
    """
    path = Path(path)
    header, arrays = _read_npz(path, surface=True)
    entry = header.get("surface")
    if entry is None or entry.get("settings") != _settings_json(settings):
        return None
    if set(arrays) != set(_SURFACE) or any(arrays[name].dtype != dtype for name, dtype in _SURFACE.items()):
        raise CorruptMapError(f"{path}: the stored surface's arrays are missing or of the wrong type")
    blocks, index = arrays["surface_blocks"], arrays["surface_block_index"]
    side = blocks.shape[1:] if blocks.ndim == 4 else None
    if (side is None or len(set(side)) != 1 or index.ndim != 3 or len(blocks) == 0 or index.min() < 0
            or index.max() >= len(blocks) or len(entry.get("origin_mm", ())) != 3):
        raise CorruptMapError(f"{path}: the stored surface's blocks {blocks.shape} and index {index.shape} disagree")
    return MapSurface(blocks=jnp.asarray(blocks), block_index=jnp.asarray(index),
                      origin=jnp.asarray(entry["origin_mm"], jnp.float32), pitch_mm=settings.pitch_mm)


def stored_features_encoder(header: dict) -> str | None:
    """The encoder of the features a map file stores (recorded by ``tactojax map`` or
    ``calibrate-belief``), or None when they are of unknown origin or absent."""
    metadata = header.get("metadata", {})
    fit = metadata.get("belief_calibration") or {}
    return metadata.get("features_encoder") or fit.get("encoder")


def maps_encoder_name(paths, encoder_name: str | None = None) -> str:
    """The encoder whose features go with the maps at ``paths``: ``encoder_name`` when given (an
    :func:`~tactojax.io.encoder_label`), else the one the maps record for their stored features
    (``features_encoder``), else the default.

    Raises:
        ValueError: no encoder given and the maps record different ones.
    """
    from tactojax.io._encoder import DEFAULT_ENCODER, encoder_label

    if encoder_name is not None:
        return encoder_label(encoder_name)
    recorded = {stored_features_encoder(tactile_map_metadata(path)) for path in paths} - {None}
    if len(recorded) > 1:
        raise ValueError(f"the maps store features of different encoders ({', '.join(sorted(recorded))}): "
                         "pass one with --encoder")
    return recorded.pop() if recorded else DEFAULT_ENCODER


def load_tactile_map_with_features(path, encoder_name: str, *, progress: bool = False) -> TactileMap:
    """The map at ``path`` with the retrieval features of the encoder ``encoder_name`` (an
    :func:`~tactojax.io.encoder_label`): those it stores when it recorded that encoder (or recorded
    none, as older maps, and it is the default), else its images encoded now (a clear error for a
    map stored without them)."""
    from tactojax.features import encode_images
    from tactojax.io._encoder import DEFAULT_ENCODER, resolve_encoder

    recorded = stored_features_encoder(tactile_map_metadata(path)) or DEFAULT_ENCODER
    tactile_map = load_tactile_map(path)
    if tactile_map.features.shape[1] > 0 and recorded == encoder_name:
        return tactile_map
    tactile_map = load_tactile_map(path, images=True)  # features of another encoder or of none: encode the images
    return tactile_map.with_features(encode_images(resolve_encoder(encoder_name), tactile_map.stored_images(),
                                                   progress=progress))


def load_localization_map(path, *, encoder_name: str | None = None, progress: bool = False):
    """A map file as localization reads it (:class:`~tactojax.localize.LocalizationMap`: its
    imprints with their retrieval features, its surface, the object's symmetries), with the
    belief calibration its header stores (``tactojax calibrate-belief``; uncalibrated without one)
    and its stored surface (:func:`stored_surface`; built now for a map that stores none).

    Args:
        path: a map written by :func:`save_tactile_map` (``tactojax map``).
        encoder_name: the encoder of the retrieval features, when not the one the map records
            (else the default): :func:`load_tactile_map_with_features`. A calibration fit with
            another encoder is not used.
        progress: show a progress bar while encoding.
    """
    from tactojax.io._encoder import DEFAULT_ENCODER, encoder_label
    from tactojax.localize import LocalizationMap, calibration_from_json

    header = tactile_map_metadata(path)
    encoder_name = maps_encoder_name([path], encoder_name or None)
    fit = header.get("metadata", {}).get("belief_calibration")
    usable = fit is not None and encoder_label(fit.get("encoder", DEFAULT_ENCODER)) == encoder_name
    tactile_map = load_tactile_map_with_features(path, encoder_name, progress=progress)
    return LocalizationMap.from_tactile_map(tactile_map, calibration=calibration_from_json(fit) if usable else None,
                                            surface=stored_surface(path))


def compact_tactile_map(source, destination, *, keep_images: bool = False, progress: bool = False) -> Path:
    """Rewrite a map file (format version 1 or 2) in the compact format, its header kept.

    Features of unknown origin (none stored, or no encoder recorded) are encoded now with the
    default encoder, so that the map stays usable without its images.

    Args:
        source: the map file to read.
        destination: the compact map to write (atomically; may be ``source``).
        keep_images: keep the tactile images (features from another encoder need them).
        progress: show a progress bar while encoding.
    """
    from tactojax.features import encode_images
    from tactojax.io._encoder import DEFAULT_ENCODER, resolve_encoder

    header = tactile_map_metadata(source)
    metadata = dict(header.get("metadata", {}))
    tactile_map = load_tactile_map(source, images=True)
    if tactile_map.features.shape[1] == 0 or stored_features_encoder(header) is None:
        features = encode_images(resolve_encoder(DEFAULT_ENCODER), tactile_map.stored_images(), progress=progress)
        tactile_map, metadata["features_encoder"] = tactile_map.with_features(features), DEFAULT_ENCODER
    if not keep_images:
        tactile_map = tactile_map.replace(images=None)
    return save_tactile_map(destination, tactile_map, metadata=metadata)


def tactile_map_bytes(path) -> dict:
    """Where a map file's bytes are: per stored array, its size in memory (the array as the
    file's version holds it) and compressed on disk; and what :func:`load_tactile_map` holds.

    Returns:
        ``{"object_id", "version", "imprints", "file_bytes", "memory_bytes", "loaded_bytes",
        "surface_bytes", "fields": {name: {"memory", "disk"}}}`` (bytes; ``memory_bytes``: the
        map's arrays, ``loaded_bytes``: the map as loaded now, without images, ``surface_bytes``:
        the stored surface, 0 without one; ``fields`` lists the surface's arrays too).
    """
    path = Path(path)
    header, arrays = _read_npz(path)
    _, surface = _read_npz(path, surface=True)
    with zipfile.ZipFile(path) as archive:
        disk = {Path(info.filename).stem: info.compress_size for info in archive.infolist()}
    fields = {name: {"memory": int(value.nbytes), "disk": disk.get(name)}
              for name, value in {**arrays, **surface}.items()}
    loaded = load_tactile_map(path)
    return {"object_id": header["object_id"], "version": int(header["version"]), "imprints": len(loaded),
            "file_bytes": path.stat().st_size, "memory_bytes": sum(fields[name]["memory"] for name in arrays),
            "loaded_bytes": sum(int(x.nbytes) for x in jax.tree.leaves(loaded)),
            "surface_bytes": sum(fields[name]["memory"] for name in surface), "fields": fields}


def update_tactile_map_metadata(path, metadata: dict) -> Path:
    """Replace a map file's ``metadata`` in place (atomically), leaving every array as it is:
    its format version, its images when it keeps them, its stored features.

    What ``tactojax calibrate-belief`` runs to store a fit: re-saving the loaded map would write
    only what the commands load (no images), and convert a version-1 file.

    Args:
        path: a map written by :func:`save_tactile_map` (or a version-1 file).
        metadata: the new JSON-serialisable ``metadata`` dict (it replaces the old one).
    """
    import io

    path = Path(path)
    header = tactile_map_metadata(path)
    header["metadata"] = metadata
    encoded = io.BytesIO()
    np.lib.format.write_array(encoded, np.array(json.dumps(header)), allow_pickle=False)
    with zipfile.ZipFile(path) as source, atomic_open(path, "wb") as handle:
        with zipfile.ZipFile(handle, "w", compression=zipfile.ZIP_DEFLATED) as target:
            for info in source.infolist():
                data = encoded.getvalue() if info.filename == "header.npy" else source.read(info)
                target.writestr(info, data, compress_type=zipfile.ZIP_DEFLATED)
    return path


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
        path: dataset directory (mapping protocol, or a real recording: its sensor jaw's
            touches, ``finger`` 0, when it holds both fingers).
        object_id: which object (required when the dataset holds several).

    Returns:
        The object's records in dataset order (``"index"`` holds their record numbers, to read
        other fields such as a simulator's ground truth with ``open_dataset(path).read``):
        ``{"object_id", "index" (K,), "images" (K, H, W, 3) uint8, "T_world_gripper" SE3 (K,), "openings" (K,)
        mm, "T_world_object" SE3 (K,) or None (a recording without it: object fixed in the
        world), "mm_per_px", "sensor", "symmetry"}``: the object's :class:`~tactojax.objects.ObjectSymmetry`
        as the simulator recorded it, or None (a recording, or a dataset written before).
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
    recording = dataset.metadata.get("protocol", {}).get("name") == "recording"
    if "finger" in dataset.fields and recording:  # a robot's recording: its sensor jaw's touches
        index = index[dataset.read(["finger"], index)["finger"] == 0]
    elif "finger" in dataset.fields and np.any(dataset.read(["finger"], index)["finger"] != 0):
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
        "symmetry": dataset_symmetry(dataset.metadata, object_id),
    }


def dataset_symmetry(metadata: dict, object_id: str) -> ObjectSymmetry | None:
    """The symmetry group a dataset's metadata records for ``object_id``, or None."""
    stored = metadata.get(symmetry_key(object_id))
    return None if stored is None else ObjectSymmetry.from_json(stored)
