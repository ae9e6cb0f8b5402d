"""A parallel-jaw grasp of a fixed object: both jaws close, the sensor jaw records an imprint.

Grasp model (compliant grasp of a fixed object). The gripper is commanded to ``T_world_gripper``
fully open. Each jaw advances along the closing axis until it touches the object: the rigid
opposite jaw stops at contact, the sensor jaw presses on by the penetration depth (the grasp
force is taken by the gel). A compliant wrist lets the gripper centre itself between the jaws,
so the recorded ``T_world_gripper`` is the commanded pose shifted along the closing axis to the
jaws' midpoint, and the opening is the distance between the two undeformed gel planes. The
finger bodies and palm are not collision-checked, only the two pads.

A grasp is *skipped* (``valid`` False) when either pad touches nothing (a miss), when a pad
starts inside the object (the object is wider than the open gripper), or when the indentation
would be deeper than the gel.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
from flax import struct
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from tactojax.geometry import opposite_sensor_pose, sensor_pose
from tactojax.objects import TactileObject
from tactojax.sensor import Imprint, SensorSpec
from tactojax.simulate._touch import cast_rays, pad_rays, touch


@dataclass(frozen=True)
class GraspConfig:
    """Gripper and contact settings of the simulator."""

    depth_mm: float = 1.0
    """Penetration depth of the gel past first contact, mm."""
    depth_noise_mm: float = 0.0
    """Standard deviation of the penetration depth across grasps, mm (clipped to >= 0.2 mm)."""
    max_opening_mm: float = 110.0
    """Largest jaw opening (WSG-50: 110 mm)."""
    opposite_pad_rays: tuple[int, int] = (24, 32)
    """Ray grid (rows, columns) sampling the rigid opposite pad, same size as the gel."""


@struct.dataclass
class GraspResult:
    """A batch of simulated grasps."""

    imprint: Imprint
    """Imprints, batch (B,). Meaningless where ``valid`` is False."""
    rigid_heightmap: Float[Array, "B H W"]
    """The object's shape at contact (indentation of a perfectly conforming gel), mm."""
    depth_mm: Float[Array, "B"]
    """Penetration depth used, mm."""
    valid: Bool[Array, "B"]
    """Whether the grasp closed on the object (see the module docstring)."""


def sample_depths(key: PRNGKeyArray, config: GraspConfig, count: int) -> Float[Array, "B"]:
    """Penetration depths for ``count`` grasps, mm."""
    noise = config.depth_noise_mm * jax.random.normal(key, (count,))
    return jnp.maximum(config.depth_mm + noise, 0.2)


def simulate_grasps(
    key: PRNGKeyArray,
    spec: SensorSpec,
    obj: TactileObject,
    T_world_object: jaxlie.SE3,
    T_world_gripper: jaxlie.SE3,
    config: GraspConfig = GraspConfig(),
) -> GraspResult:
    """Simulate a batch of grasps of a fixed object.

    Args:
        key: PRNG key (depth noise, camera noise).
        spec: the sensor on the sensor jaw.
        obj: the object, placed in the world by ``T_world_object`` (a single pose).
        T_world_gripper: (B,) commanded gripper poses, mm.
        config: gripper and contact settings.

    Returns:
        :class:`GraspResult` of batch (B,).
    """
    depth_key, noise_key = jax.random.split(key)
    count = T_world_gripper.get_batch_axes()[0]
    depths = sample_depths(depth_key, config, count)
    T_object_world = T_world_object.inverse()
    max_opening = jnp.full((count,), config.max_opening_mm)

    T_object_sensor = T_object_world @ sensor_pose(T_world_gripper, max_opening)
    contact, images, sensor_collides = touch(
        noise_key, spec, obj, T_object_sensor, depths, max_distance=config.max_opening_mm
    )

    rows, cols = config.opposite_pad_rays
    pad_mm_per_px = spec.mm_per_px * spec.width_px / cols
    T_object_opposite = T_object_world @ opposite_sensor_pose(T_world_gripper, max_opening)
    origins, directions = pad_rays(T_object_opposite, rows, cols, pad_mm_per_px)
    opposite = cast_rays(obj, origins, directions, max_distance=config.max_opening_mm)
    opposite_touched = jnp.any(opposite.hit, axis=(-2, -1))
    opposite_travel = jnp.min(jnp.where(opposite.hit, opposite.distance, jnp.inf), axis=(-2, -1))
    opposite_travel = jnp.where(opposite_touched, opposite_travel, 0.0)
    opposite_collides = jnp.any(opposite.starts_inside, axis=(-2, -1))

    opening = config.max_opening_mm - contact.travel - opposite_travel
    shift = jnp.stack([jnp.zeros(count), (opposite_travel - contact.travel) / 2, jnp.zeros(count)], -1)
    T_world_gripper_final = T_world_gripper @ jaxlie.SE3.from_translation(shift)
    valid = (
        contact.touched & opposite_touched & ~sensor_collides & ~opposite_collides
        & (opening > 0) & (jnp.max(contact.rigid_heightmap, axis=(-2, -1)) < spec.gel_thickness_mm)
    )
    imprint = Imprint(
        image=images,
        opening=opening,
        T_world_sensor=sensor_pose(T_world_gripper_final, opening),
        T_world_gripper=T_world_gripper_final,
        heightmap=contact.heightmap,
        mask=contact.mask,
        has_ground_truth=jnp.ones((count,), bool),
    )
    return GraspResult(imprint=imprint, rigid_heightmap=contact.rigid_heightmap, depth_mm=depths, valid=valid)
