"""New-grasps test sets (datasets of ``tactojax.simulate.GraspsProtocol``) read back as arrays, and as
the :class:`~tactojax.localize.TestEpisodes` that localization evaluates."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tactojax.io._dataset import open_dataset

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


def load_test_episodes(path: str | Path, object_id: str, model, encoder, *, progress: bool = True):
    """The test grasps of ``object_id`` as :class:`~tactojax.localize.TestEpisodes`.

    Heightmaps and masks are *predicted* from the images by ``model`` (as a robot would), the
    features come from ``encoder``, the true poses and the true contact clouds (for the error)
    from the simulator.

    Args:
        path: a new-grasps dataset (``tactojax simulate OBJECT --protocol grasps``).
        object_id: whose episodes to read.
        model: the shape model (:class:`~tactojax.shape.ShapeModel`) of the map's sensor.
        encoder: the retrieval encoder the map's features were computed with.
        progress: show a progress bar while encoding.

    Returns:
        (episodes, fingers recorded per grasp).
    """
    import jax
    import jax.numpy as jnp
    import jaxlie

    from tactojax.features import encode_images
    from tactojax.geometry import heightmap_to_points
    from tactojax.localize import TestEpisodes
    from tactojax.localize._evaluate import cloud_moments
    from tactojax.mapping import observed_contact
    from tactojax.shape import predict_batch

    data = read_test_grasps(path, ["image", "heightmap", "mask", "T_world_sensor", "T_world_object", "opening_mm"],
                            object_id=object_id)
    if tuple(data["image"].shape[1:3]) != tuple(model.image_shape):
        raise ValueError(f"the test images are {data['image'].shape[1:3]} px but the shape model takes "
                         f"{model.image_shape}: simulate the test set with the map's sensor and scale")
    episode, grasp, finger = data["episode"], data["grasp"], data["finger"]
    grasps, fingers = int(grasp.max()) + 1, int(finger.max()) + 1
    count = len(episode) // (grasps * fingers)

    def shaped(x):
        return np.asarray(x).reshape(count, grasps, fingers, *np.asarray(x).shape[1:])

    pixels = data["image"].astype(np.float32) / 255.0
    heightmaps, masks = predict_batch(model, pixels)
    masks = jax.vmap(lambda p, m: observed_contact(p, model.background, m, model.mm_per_px))(jnp.asarray(pixels), masks)
    features = encode_images(encoder, data["image"], progress=progress)
    T_object_sensor = (jaxlie.SE3(jnp.asarray(data["T_world_object"])).inverse()
                       @ jaxlie.SE3(jnp.asarray(data["T_world_sensor"])))
    points = jax.vmap(lambda h: heightmap_to_points(h, model.mm_per_px).reshape(-1, 3))(jnp.asarray(data["heightmap"]))
    mean, covariance = jax.vmap(cloud_moments)(points, jnp.asarray(data["mask"]).reshape(len(points), -1))
    episodes = TestEpisodes(
        heightmaps=jnp.asarray(shaped(heightmaps)), masks=jnp.asarray(shaped(masks)),
        features=jnp.asarray(shaped(features)), openings=jnp.asarray(shaped(data["opening_mm"])[:, :, 0]),
        T_object_sensor=jaxlie.SE3(jnp.asarray(shaped(T_object_sensor.wxyz_xyz))),
        cloud_mean=jnp.asarray(shaped(mean)), cloud_covariance=jnp.asarray(shaped(covariance)))
    return episodes, fingers
