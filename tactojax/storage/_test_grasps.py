"""New-grasps test sets (datasets of ``tactojax.simulate.GraspsProtocol``) read back as arrays, checked
complete (``tactojax.localize.evaluation.load_test_episodes`` turns them into the episodes that localization evaluates)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tactojax.storage._dataset import open_dataset

_IDS = ("object_id", "episode", "grasp", "finger")


def read_test_grasps(path: str | Path, fields=None, *, object_id: str | None = None) -> dict[str, np.ndarray]:
    """The records of a new-grasps dataset, checked complete, as ``{field: (N, ...) array}``.

    Records come in dataset order: by episode, then grasp, then finger. Every
    ``(object_id, episode)`` holds ``grasps_per_episode * fingers`` records (the dataset
    metadata's ``protocol``), so ``array.reshape(-1, grasps_per_episode, fingers, ...)`` gives
    (episode, grasp, finger) axes.

    Args:
        path: dataset directory written with the ``grasps`` protocol.
        fields: fields to read (default all; leave out ``image`` to read less). ``object_id``,
            ``episode``, ``grasp`` and ``finger`` are always read.
        object_id: keep only this object's episodes (default all).

    Returns:
        ``{field: array}``: ``image`` (N, H, W, 3) uint8, ``heightmap`` (N, H, W) mm, ``mask``,
        ``T_world_sensor``/``T_world_gripper``/``T_world_object`` (N, 7) wxyz + xyz (mm),
        ``opening_mm``, ``depth_mm``, ``object_id`` (N,) str, ``episode``, ``grasp``, ``finger``
        (N,) int64, ``turn_rad``, ``yaw_rad``.

    Raises:
        ValueError: not a new-grasps dataset, an unknown object, or an incomplete episode (an
            interrupted run).
    """
    dataset = open_dataset(path)
    protocol = dataset.metadata.get("protocol", {})
    if protocol.get("name") != "grasps":
        raise ValueError(f"dataset {path} holds the {protocol.get('name', '?')!r} protocol, not new grasps "
                         "(make one with `tactojax simulate OBJECT --protocol grasps`)")
    grasps, fingers = int(protocol["grasps_per_episode"]), int(protocol["fingers"])
    ids = dataset.read(_IDS)
    index = np.arange(len(dataset))
    if object_id is not None:
        names = sorted(set(ids["object_id"].tolist()))
        if object_id not in names:
            raise ValueError(f"object {object_id!r} is not in dataset {path} (have {names})")
        index = np.flatnonzero(ids["object_id"] == object_id)
    _check_complete(path, {name: values[index] for name, values in ids.items()}, grasps, fingers)
    names = dataset.fields if fields is None else tuple(dict.fromkeys([*fields, *_IDS]))
    return dataset.read(names, index)


def _check_complete(path, ids: dict[str, np.ndarray], grasps: int, fingers: int) -> None:
    size = grasps * fingers
    if len(ids["episode"]) % size == 0:
        rows = {name: values.reshape(-1, size) for name, values in ids.items()}
        same_episode = all(np.all(rows[name] == rows[name][:, :1]) for name in ("object_id", "episode"))
        in_order = (np.all(rows["grasp"] == np.repeat(np.arange(grasps), fingers))
                    and np.all(rows["finger"] == np.tile(np.arange(fingers), grasps)))
        keys = list(zip(rows["object_id"][:, 0].tolist(), rows["episode"][:, 0].tolist(), strict=True))
        if same_episode and in_order and len(set(keys)) == len(keys):
            return
    raise ValueError(f"dataset {path}: episodes are not {grasps} grasps x {fingers} fingers each, in order "
                     "(an interrupted run? simulate again into a new directory)")
