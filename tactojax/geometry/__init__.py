"""Geometry: pixel grids, heightmap -> points/normals, gripper kinematics, indexing batched poses (pure JAX)."""

from tactojax.geometry._heightmap import contact_points as contact_points
from tactojax.geometry._heightmap import heightmap_gradient as heightmap_gradient
from tactojax.geometry._heightmap import heightmap_normals as heightmap_normals
from tactojax.geometry._heightmap import heightmap_to_points as heightmap_to_points
from tactojax.geometry._kinematics import T_gripper_sensor as T_gripper_sensor
from tactojax.geometry._kinematics import gripper_pose as gripper_pose
from tactojax.geometry._kinematics import opposite_sensor_pose as opposite_sensor_pose
from tactojax.geometry._kinematics import sensor_pose as sensor_pose
from tactojax.geometry._pixels import pixel_grid as pixel_grid
from tactojax.geometry._trees import take as take

__all__ = [
    "T_gripper_sensor",
    "contact_points",
    "gripper_pose",
    "heightmap_gradient",
    "heightmap_normals",
    "heightmap_to_points",
    "opposite_sensor_pose",
    "pixel_grid",
    "sensor_pose",
    "take",
]
