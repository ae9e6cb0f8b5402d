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

import math
from collections.abc import Sequence

import jax.numpy as jnp
import jaxlie
import numpy as np
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


Pose = tuple[float, float, float, float, float, float, float]
"""A pose as plain floats, wxyz_xyz: the host twins below (the live loop's per-frame arithmetic)."""


def _quaternion_product(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float, float]:
    """Hamilton product of wxyz quaternions (jaxlie's ``SO3.multiply``)."""
    w0, x0, y0, z0 = a
    w1, x1, y1, z1 = b
    return (w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1, w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
            w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1, w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1)


def _rotate(wxyz: Sequence[float], vector: Sequence[float]) -> tuple[float, float, float]:
    """A 3-vector turned by a unit quaternion (q v q*)."""
    w, x, y, z = wxyz
    return _quaternion_product(_quaternion_product(wxyz, (0.0, *vector)), (w, -x, -y, -z))[1:]


def compose_on_host(T_a: Pose, T_b: Pose) -> Pose:
    """``T_a @ T_b`` in plain floats."""
    t = _rotate(T_a[:4], T_b[4:])
    return (*_quaternion_product(T_a[:4], T_b[:4]), T_a[4] + t[0], T_a[5] + t[1], T_a[6] + t[2])


def inverse_on_host(T: Pose) -> Pose:
    """The inverse pose, in plain floats."""
    w, x, y, z = T[:4]
    t = _rotate((w, -x, -y, -z), T[4:])
    return (w, -x, -y, -z, -t[0], -t[1], -t[2])


_WXYZ_GRIPPER_SENSOR = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)
"""The sensor frame's rotation in the gripper frame (:func:`T_gripper_sensor`:
x_s = x_g, y_s = z_g, z_s = -y_g, a quarter turn about x)."""
_FLIP_ABOUT_Z = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
"""A half turn about the gripper's z axis: the opposite finger (:func:`opposite_sensor_pose`)."""


def as_host_pose(wxyz_xyz) -> Pose:
    """A (7,) wxyz_xyz array as plain floats (double precision)."""
    return tuple(np.asarray(wxyz_xyz, np.float64).tolist())


def finger_poses_on_host(T_world_gripper: Pose, opening: float) -> tuple[Pose, Pose]:
    """:func:`sensor_pose` and :func:`opposite_sensor_pose` in plain floats: both fingers'
    ``T_world_sensor`` for a gripper pose and opening (mm). No dispatch, no compilation: a few
    tens of microseconds, for the live loop's every frame."""
    T_gripper_sensor = (*_WXYZ_GRIPPER_SENSOR, 0.0, 0.5 * opening, 0.0)
    return (compose_on_host(T_world_gripper, T_gripper_sensor),
            compose_on_host(compose_on_host(T_world_gripper, _FLIP_ABOUT_Z), T_gripper_sensor))
