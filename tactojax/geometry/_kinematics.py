"""Parallel-jaw gripper kinematics: gripper pose + opening -> sensor poses.

Gripper frame (``gripper``): origin midway between the two undeformed gel surfaces, z along the
approach direction (out of the palm, towards the object), y along the closing axis pointing at
the sensor finger, x = y cross z. The opening is the distance between the two undeformed gel
surfaces, in mm.

The sensor finger sits at y = +opening / 2 with its gel facing the other jaw, so its z axis
(out of the gel, towards the object) is -y_gripper; its x axis (image columns) is x_gripper and
its y axis (image rows) is z_gripper, i.e. image rows run along the approach direction. The
opposite finger is the same finger turned by pi about the gripper's z axis.
"""

from __future__ import annotations

import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Float

# Rotation taking sensor-frame vectors to gripper-frame vectors: columns are the sensor axes
# expressed in the gripper frame (x_s = x_g, y_s = z_g, z_s = -y_g).
_R_GRIPPER_SENSOR = jnp.array(
    [[1.0, 0.0, 0.0],
     [0.0, 0.0, -1.0],
     [0.0, 1.0, 0.0]]
)


def T_gripper_sensor(opening: Float[Array, "*batch"]) -> jaxlie.SE3:
    """Pose of the sensor finger's gel frame in the gripper frame.

    Args:
        opening: (*batch) jaw opening, mm.

    Returns:
        SE3 with batch shape (*batch).
    """
    opening = jnp.asarray(opening, dtype=jnp.float32)
    rotation = jaxlie.SO3.from_matrix(_R_GRIPPER_SENSOR)
    translation = jnp.stack(
        [jnp.zeros_like(opening), opening / 2.0, jnp.zeros_like(opening)], axis=-1
    )
    wxyz = jnp.broadcast_to(rotation.wxyz, opening.shape + (4,))
    return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3(wxyz), translation)


def sensor_pose(T_world_gripper: jaxlie.SE3, opening: Float[Array, "*batch"]) -> jaxlie.SE3:
    """``T_world_sensor`` of the sensor finger for a gripper pose and jaw opening.

    Args:
        T_world_gripper: gripper pose, batch shape (*batch).
        opening: (*batch) jaw opening, mm.

    Returns:
        T_world_sensor, batch shape (*batch).
    """
    return T_world_gripper @ T_gripper_sensor(opening)


def opposite_sensor_pose(
    T_world_gripper: jaxlie.SE3, opening: Float[Array, "*batch"]
) -> jaxlie.SE3:
    """``T_world_sensor`` of the opposite finger (for two-sensor grippers).

    The opposite finger is the sensor finger turned by pi about the gripper z axis, so its gel
    also faces the grasp centre and its image rows also run along the approach direction.
    """
    flip = jaxlie.SE3.from_rotation(jaxlie.SO3.from_z_radians(jnp.pi))
    return T_world_gripper @ flip @ T_gripper_sensor(opening)


def gripper_pose(T_world_sensor: jaxlie.SE3, opening: Float[Array, "*batch"]) -> jaxlie.SE3:
    """Inverse of :func:`sensor_pose`: ``T_world_gripper`` from the sensor pose and opening."""
    return T_world_sensor @ T_gripper_sensor(opening).inverse()
