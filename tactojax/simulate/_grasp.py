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

Two-sensor grasps (:func:`simulate_two_sensor_grasps`): the opposite jaw carries a gel sensor of
the same kind instead of the rigid pad. Both gels press on by the grasp's penetration depth, so
each jaw travels to its first contact plus that depth; the wrist, the opening and the skip rules
are as above, with both gels' contacts.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from tactojax import _struct as struct
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
    """Imprints, batch (B,), or (B, 2) for two-sensor grasps (finger 0: the sensor jaw, 1: the
    opposite jaw). Meaningless where ``valid`` is False."""
    rigid_heightmap: Float[Array, "B *F H W"]
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
        obj: the object, placed in the world by ``T_world_object`` (one pose, or (B,): one per grasp).
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

    opening, T_world_gripper_final = _close_jaws(T_world_gripper, contact.travel, opposite_travel, config)
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


def simulate_two_sensor_grasps(
    key: PRNGKeyArray,
    spec: SensorSpec,
    obj: TactileObject,
    T_world_object: jaxlie.SE3,
    T_world_gripper: jaxlie.SE3,
    config: GraspConfig = GraspConfig(),
) -> GraspResult:
    """Simulate a batch of grasps with a gel sensor of the same kind on both jaws.

    Both gels press on by the grasp's penetration depth (one depth per grasp, drawn as in
    :func:`simulate_grasps`). Finger 0 (the sensor jaw) is at ``sensor_pose(T_world_gripper,
    opening)``, finger 1 (the opposite jaw) at ``opposite_sensor_pose(T_world_gripper, opening)``
    of the recorded gripper pose.

    Args:
        key: PRNG key (depth noise, camera noise).
        spec: the sensor on each jaw.
        obj: the object, placed in the world by ``T_world_object`` (one pose, or (B,): one per grasp).
        T_world_gripper: (B,) commanded gripper poses, mm.
        config: gripper and contact settings (``opposite_pad_rays`` is unused).

    Returns:
        :class:`GraspResult` whose imprint batch is (B, 2) (grasp, finger); ``depth_mm`` and
        ``valid`` are (B,).
    """
    depth_key, noise_key = jax.random.split(key)
    count = T_world_gripper.get_batch_axes()[0]
    depths = sample_depths(depth_key, config, count)
    T_object_world = T_world_object.inverse()
    max_opening = jnp.full((count,), config.max_opening_mm)
    starts = [T_object_world @ pose(T_world_gripper, max_opening) for pose in (sensor_pose, opposite_sensor_pose)]
    # Both jaws in one batch of 2B touches, grasp-major: (grasp 0 finger 0, grasp 0 finger 1, ...).
    T_object_start = jax.tree.map(lambda a, b: jnp.stack([a, b], axis=1).reshape(2 * count, -1), *starts)
    contact, images, collides = touch(noise_key, spec, obj, T_object_start, jnp.repeat(depths, 2),
                                      max_distance=config.max_opening_mm)
    contact, images, collides = jax.tree.map(lambda x: x.reshape(count, 2, *x.shape[1:]),
                                             (contact, images, collides))

    opening, T_world_gripper_final = _close_jaws(T_world_gripper, contact.travel[:, 0], contact.travel[:, 1],
                                                 config)
    valid = (
        jnp.all(contact.touched, axis=1) & ~jnp.any(collides, axis=1) & (opening > 0)
        & jnp.all(jnp.max(contact.rigid_heightmap, axis=(-2, -1)) < spec.gel_thickness_mm, axis=1)
    )
    T_world_sensor = jax.tree.map(lambda a, b: jnp.stack([a, b], axis=1),
                                  sensor_pose(T_world_gripper_final, opening),
                                  opposite_sensor_pose(T_world_gripper_final, opening))
    imprint = Imprint(
        image=images,
        opening=jnp.repeat(opening[:, None], 2, axis=1),
        T_world_sensor=T_world_sensor,
        T_world_gripper=jax.tree.map(lambda x: jnp.repeat(x[:, None], 2, axis=1), T_world_gripper_final),
        heightmap=contact.heightmap,
        mask=contact.mask,
        has_ground_truth=jnp.ones((count, 2), bool),
    )
    return GraspResult(imprint=imprint, rigid_heightmap=contact.rigid_heightmap, depth_mm=depths, valid=valid)


def _close_jaws(
    T_world_gripper: jaxlie.SE3, sensor_travel: Float[Array, "B"], opposite_travel: Float[Array, "B"],
    config: GraspConfig,
) -> tuple[Float[Array, "B"], jaxlie.SE3]:
    """Opening and re-centred gripper pose once the jaws travelled (compliant wrist), mm."""
    opening = config.max_opening_mm - sensor_travel - opposite_travel
    zeros = jnp.zeros_like(opening)
    shift = jnp.stack([zeros, (opposite_travel - sensor_travel) / 2, zeros], -1)
    return opening, T_world_gripper @ jaxlie.SE3.from_translation(shift)
