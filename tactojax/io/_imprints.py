"""Imprint datasets read back as :class:`~tactojax.sensor.Imprint` batches (written by
``tactojax.simulate.simulate_to_dataset`` or recorded; the record fields are listed there)."""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.sensor import Imprint
from tactojax.storage._dataset import open_dataset


def load_imprints(path: str | Path, indices=None) -> tuple[Imprint, np.ndarray]:
    """Read imprints from a dataset as an :class:`Imprint` batch (images as float in [0, 1]).

    Args:
        path: dataset directory.
        indices: optional slice or integer array of records.

    Returns:
        (imprints with batch (N,), object ids (N,) str).
    """
    fields = ["image", "heightmap", "mask", "T_world_sensor", "T_world_gripper", "opening_mm", "object_id"]
    data = open_dataset(path).read(fields, indices)
    count = data["image"].shape[0]
    imprint = Imprint(
        image=jnp.asarray(data["image"], jnp.float32) / 255.0,
        opening=jnp.asarray(data["opening_mm"]),
        T_world_sensor=jaxlie.SE3(jnp.asarray(data["T_world_sensor"])),
        T_world_gripper=jaxlie.SE3(jnp.asarray(data["T_world_gripper"])),
        heightmap=jnp.asarray(data["heightmap"]),
        mask=jnp.asarray(data["mask"]),
        has_ground_truth=jnp.ones((count,), bool),
    )
    return imprint, data["object_id"]
