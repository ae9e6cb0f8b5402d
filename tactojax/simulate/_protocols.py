"""Exploration protocols (paper sections IV and V) as plans of grasps and touches.

Mapping (section V). The object is fixed in the world, turned about the vertical (world z) by
each of ``turns_deg``. The gripper comes from above (its approach axis is world -z) with its
closing axis horizontal, turned about the vertical by each of ``yaws_deg``. For each (turn,
yaw) the grasp centres form an equispaced grid (``grid_mm``) in the plane of the gripper (the
vertical plane normal to the closing axis), centred on and covering the object's bounding box
as seen in that plane; along the closing axis each grasp is centred on the box. Grasps that
miss, or that the open gripper cannot fit around, are skipped when simulated.

Calibration (section IV). Frontal touches: the sensor faces straight down onto the shape (whose
top points up, +z), turned by a random angle about its normal, shifted so that the shape's axis
crosses the gel at a random offset from the image centre (uniform, up to
``max_offset_fraction`` of the field of view each way, in the sensor frame), and pressed to a
random depth in ``depth_range_mm``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from flax import struct
from jaxtyping import Array, Float, PRNGKeyArray

from tactojax.objects import TactileObject
from tactojax.sensor import SensorSpec

# Top-down gripper at yaw 0: x along world x, closing axis y along world -y, approach z down.
_R_WORLD_GRIPPER_0 = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


@dataclass(frozen=True)
class MappingProtocol:
    """Grasps on a grid in the plane of the gripper (paper section V)."""

    grid_mm: float = 10.0
    yaws_deg: tuple[float, ...] = (0.0, 20.0, -20.0)
    turns_deg: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)
    name: str = "mapping"


@dataclass(frozen=True)
class CalibrationProtocol:
    """Random frontal touches of a calibration shape (paper section IV)."""

    touches: int = 600
    depth_range_mm: tuple[float, float] = (0.5, 1.5)
    max_offset_fraction: float = 0.3
    clearance_mm: float = 2.0
    name: str = "calibration"


@struct.dataclass
class GraspPlan:
    """G planned grasps (mapping protocol)."""

    T_world_object: jaxlie.SE3
    """(G,) object poses (the object turned about world z)."""
    T_world_gripper: jaxlie.SE3
    """(G,) commanded gripper poses, fully open."""
    turn_rad: Float[Array, "G"]
    yaw_rad: Float[Array, "G"]
    grid_u_mm: Float[Array, "G"]
    """Grid coordinate along the gripper's x axis (horizontal), mm."""
    grid_v_mm: Float[Array, "G"]
    """Grid coordinate along world z (height), mm."""

    def __len__(self) -> int:
        return int(self.turn_rad.shape[0])


@struct.dataclass
class TouchPlan:
    """N planned frontal touches (calibration protocol)."""

    T_world_sensor_start: jaxlie.SE3
    """(N,) sensor poses before pressing, gel facing down; the object sits at the world origin."""
    depth_mm: Float[Array, "N"]
    rotation_rad: Float[Array, "N"]
    offset_x_mm: Float[Array, "N"]
    """Where the shape's axis crosses the gel, sensor-frame x, mm."""
    offset_y_mm: Float[Array, "N"]

    def __len__(self) -> int:
        return int(self.depth_mm.shape[0])


def _box_corners(bounds: np.ndarray) -> np.ndarray:
    return np.array(list(itertools.product(*bounds.T)))  # (8, 3)


def _grid(lo: float, hi: float, spacing: float) -> np.ndarray:
    """Equispaced points centred on [lo, hi], covering it."""
    count = int(math.floor((hi - lo) / spacing)) + 1
    return 0.5 * (lo + hi) + (np.arange(count) - (count - 1) / 2.0) * spacing


def mapping_plan(obj: TactileObject, protocol: MappingProtocol = MappingProtocol()) -> GraspPlan:
    """All grasps of the mapping protocol for ``obj`` (see the module docstring)."""
    if protocol.grid_mm <= 0:
        raise ValueError(f"grid spacing must be positive, got {protocol.grid_mm} mm")
    rows = []
    corners = _box_corners(obj.bounds)
    for turn_deg in protocol.turns_deg:
        R_world_object = _rot_z(math.radians(turn_deg))
        corners_world = corners @ R_world_object.T
        for yaw_deg in protocol.yaws_deg:
            R_world_gripper = _rot_z(math.radians(yaw_deg)) @ _R_WORLD_GRIPPER_0
            # Corners in the yawed gripper axes: u along gripper x, c along the closing axis.
            u = corners_world @ R_world_gripper[:, 0]
            c = corners_world @ R_world_gripper[:, 1]
            z = corners_world[:, 2]
            centre_c = 0.5 * (c.min() + c.max())
            for grid_u in _grid(u.min(), u.max(), protocol.grid_mm):
                for grid_v in _grid(z.min(), z.max(), protocol.grid_mm):
                    position = grid_u * R_world_gripper[:, 0] + centre_c * R_world_gripper[:, 1]
                    position[2] = grid_v
                    rows.append((turn_deg, yaw_deg, grid_u, grid_v, R_world_object, R_world_gripper, position))
    turn, yaw, grid_u, grid_v, R_wo, R_wg, p_wg = (np.array(column) for column in zip(*rows))
    return GraspPlan(
        T_world_object=jaxlie.SE3.from_rotation(jaxlie.SO3.from_matrix(jnp.asarray(R_wo, jnp.float32))),
        T_world_gripper=jaxlie.SE3.from_rotation_and_translation(
            jaxlie.SO3.from_matrix(jnp.asarray(R_wg, jnp.float32)), jnp.asarray(p_wg, jnp.float32)),
        turn_rad=jnp.deg2rad(jnp.asarray(turn, jnp.float32)),
        yaw_rad=jnp.deg2rad(jnp.asarray(yaw, jnp.float32)),
        grid_u_mm=jnp.asarray(grid_u, jnp.float32),
        grid_v_mm=jnp.asarray(grid_v, jnp.float32),
    )


def calibration_plan(
    key: PRNGKeyArray, obj: TactileObject, spec: SensorSpec,
    protocol: CalibrationProtocol = CalibrationProtocol(),
) -> TouchPlan:
    """Random frontal touches of ``obj`` (see the module docstring)."""
    if protocol.touches <= 0:
        raise ValueError(f"need a positive number of touches, got {protocol.touches}")
    count = protocol.touches
    k_depth, k_rot, k_x, k_y = jax.random.split(key, 4)
    fov_x, fov_y = spec.field_of_view_mm
    f = protocol.max_offset_fraction
    depth = jax.random.uniform(k_depth, (count,), minval=protocol.depth_range_mm[0], maxval=protocol.depth_range_mm[1])
    rotation = jax.random.uniform(k_rot, (count,), minval=0.0, maxval=2 * jnp.pi)
    offset_x = jax.random.uniform(k_x, (count,), minval=-f * fov_x, maxval=f * fov_x)
    offset_y = jax.random.uniform(k_y, (count,), minval=-f * fov_y, maxval=f * fov_y)
    # Gel facing down (sensor z = world -z), turned about its normal.
    facing_down = jaxlie.SO3.from_x_radians(jnp.pi)
    R = jaxlie.SO3.from_z_radians(rotation) @ facing_down
    # Place the sensor so that the shape's vertical axis crosses the gel at (offset_x, offset_y)
    # in the sensor frame: p_sensor(axis) = R^T (0 - position) has x, y = offsets.
    top = float(obj.bounds[1, 2]) + protocol.clearance_mm
    in_plane = -(R @ jnp.stack([offset_x, offset_y, jnp.zeros(count)], axis=-1))
    position = in_plane.at[:, 2].set(top)
    return TouchPlan(
        T_world_sensor_start=jaxlie.SE3.from_rotation_and_translation(R, position),
        depth_mm=depth, rotation_rad=rotation, offset_x_mm=offset_x, offset_y_mm=offset_y,
    )


def _rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
