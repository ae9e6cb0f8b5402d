"""Imprint: one touch, as a sensor (real or simulated) records it."""

from __future__ import annotations

import jaxlie
from jaxtyping import Array, Bool, Float

from tactojax import _struct as struct


@struct.dataclass
class Imprint:
    """One tactile imprint. Batches stack every field along leading axes.

    ``heightmap`` and ``mask`` are the ground truth when the imprint is simulated; real
    recordings leave them as zeros / False with ``has_ground_truth`` False.
    """

    image: Float[Array, "*batch H W 3"]
    """Tactile RGB image in [0, 1]."""
    opening: Float[Array, "*batch"]
    """Gripper opening (distance between the undeformed gel surfaces), mm."""
    T_world_sensor: jaxlie.SE3
    """Pose of the sensor's gel frame in the world, mm."""
    T_world_gripper: jaxlie.SE3
    """Pose of the gripper frame in the world, mm."""
    heightmap: Float[Array, "*batch H W"]
    """Gel indentation depth, mm (>= 0)."""
    mask: Bool[Array, "*batch H W"]
    """Contact mask."""
    has_ground_truth: Bool[Array, "*batch"]
    """Whether ``heightmap``/``mask`` hold ground truth."""
