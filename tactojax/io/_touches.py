"""Touches with their poses in the object frame, read from grasp datasets (encoder training data)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tactojax.features._touches import TouchData
from tactojax.geometry import sensor_pose
from tactojax.storage._dataset import open_dataset
from tactojax.io._map import read_grasps


def catalog_symmetry(object_id: str) -> np.ndarray:
    """(S, 4, 4) symmetry transforms of a catalog object, or just the identity for others."""
    from tactojax.objects import object_symmetry

    return np.asarray(object_symmetry(object_id).transforms().as_matrix(), np.float32)


def load_touches(paths, *, objects: list[str] | None = None, symmetries: bool = True) -> TouchData:
    """Every imprint of grasp datasets with its sensor pose in its object's frame.

    Args:
        paths: dataset directories (mapping protocol or recordings with ``T_world_object``;
            without it the object is taken as fixed in the world).
        objects: keep only these object ids (default all).
        symmetries: attach the symmetry group of catalog objects (by object id; others get
            none), so that retrieval and training compare poses up to symmetry.

    Returns:
        The touches; an object appearing in several datasets is one object (same frame).
    """
    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    if not paths:
        raise ValueError("no dataset given")
    names: list[str] = []
    parts = []
    shapes = set()
    for path in paths:
        ids = sorted(set(open_dataset(path).read(["object_id"])["object_id"].astype(str).tolist()))
        for object_id in ids:
            if objects is not None and object_id not in objects:
                continue
            grasps = read_grasps(path, object_id=object_id)
            T_world_sensor = sensor_pose(grasps["T_world_gripper"], grasps["openings"])
            T_object_sensor = (T_world_sensor if grasps["T_world_object"] is None
                               else grasps["T_world_object"].inverse() @ T_world_sensor)
            if object_id not in names:
                names.append(str(object_id))
            shapes.add(grasps["images"].shape[1:])
            parts.append((grasps["images"], names.index(object_id), np.asarray(T_object_sensor.translation()),
                          np.asarray(T_object_sensor.rotation().as_matrix()), np.asarray(grasps["openings"])))
    if not parts:
        raise ValueError(f"no touches of objects {objects} in {[str(p) for p in paths]}")
    if len(shapes) > 1:
        raise ValueError(f"datasets mix image sizes: {sorted(shapes)}")
    return TouchData(
        images=np.concatenate([p[0] for p in parts]),
        object_index=np.concatenate([np.full(len(p[0]), p[1], np.int32) for p in parts]),
        positions=np.concatenate([p[2] for p in parts]).astype(np.float32),
        rotations=np.concatenate([p[3] for p in parts]).astype(np.float32),
        openings=np.concatenate([p[4] for p in parts]).astype(np.float32), objects=tuple(names),
        symmetries=tuple(catalog_symmetry(name) for name in names) if symmetries else ())
