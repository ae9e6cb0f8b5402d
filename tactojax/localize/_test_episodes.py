"""New-grasps test sets as the :class:`TestEpisodes` that the evaluation localizes: the shape
network and the encoder run on the recorded images, as a robot's would."""

from __future__ import annotations

import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.features import encode_images
from tactojax.geometry import heightmap_to_points
from tactojax.localize._evaluate import cloud_moments
from tactojax.localize._episode_beliefs import TestEpisodes
from tactojax.mapping import observed_contact
from tactojax.shape import predict_batch
from tactojax.storage._test_grasps import read_test_grasps


def load_test_episodes(path: str | Path, object_id: str, model, encoder, *, progress: bool = True):
    """The test grasps of ``object_id`` as :class:`~tactojax.localize.evaluation.TestEpisodes`.

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
    masks, T_object_sensor, mean, covariance = _observed_and_true(
        jnp.asarray(pixels), masks, model.background, jnp.asarray(data["heightmap"]), jnp.asarray(data["mask"]),
        jaxlie.SE3(jnp.asarray(data["T_world_object"])), jaxlie.SE3(jnp.asarray(data["T_world_sensor"])),
        mm_per_px=model.mm_per_px)
    features = encode_images(encoder, data["image"], progress=progress)
    episodes = TestEpisodes(
        heightmaps=jnp.asarray(shaped(heightmaps)), masks=jnp.asarray(shaped(masks)),
        features=jnp.asarray(shaped(features)), openings=jnp.asarray(shaped(data["opening_mm"])[:, :, 0]),
        T_object_sensor=jaxlie.SE3(jnp.asarray(shaped(T_object_sensor.wxyz_xyz))),
        cloud_mean=jnp.asarray(shaped(mean)), cloud_covariance=jnp.asarray(shaped(covariance)))
    return episodes, fingers


@functools.partial(jax.jit, static_argnames=("mm_per_px",))
def _observed_and_true(pixels, predicted_masks, background, true_heightmaps, true_masks, T_world_object: jaxlie.SE3,
                       T_world_sensor: jaxlie.SE3, mm_per_px: float):
    """(N,) touches: the predicted masks kept where the image changed (:func:`observed_contact`),
    the sensors' true poses in the object frame, and the true contact clouds' moments; one
    program (eagerly, each of its dozens of operations compiled apart, per test-set size)."""
    masks = jax.vmap(lambda p, m: observed_contact(p, background, m, mm_per_px))(pixels, predicted_masks)
    points = jax.vmap(lambda h: heightmap_to_points(h, mm_per_px).reshape(-1, 3))(true_heightmaps)
    mean, covariance = jax.vmap(cloud_moments)(points, true_masks.reshape(len(points), -1))
    return masks, T_world_object.inverse() @ T_world_sensor, mean, covariance
