"""Exploration protocols (paper sections IV and V) as plans of grasps and touches.

Mapping (section V). The object is fixed in the world, turned about the vertical (world z) by
each of ``turns_deg``. The gripper comes from above (its approach axis is world -z) with its
closing axis horizontal, turned about the vertical by each of ``yaws_deg``. For each (turn,
yaw) the grasp centres form an equispaced grid (``grid_mm``) in the plane of the gripper (the
vertical plane normal to the closing axis), centred on and covering the object's bounding box
as seen in that plane; along the closing axis each grasp is centred on the box. Grasps that
miss, or that the open gripper cannot fit around, are skipped when simulated.

New grasps (a localization test set, off the mapping grid). Episodes: each places the object
as one mapping turn, drawn uniformly from ``turns_deg``, and makes ``grasps_per_episode`` grasps
from above like the mapping protocol, each with its own gripper yaw (uniform within
``±yaw_range_deg``) and centre (uniform over the object's bounding box as seen in the plane of
the gripper at that yaw; centred on the box along the closing axis). Positions and yaws are
continuous. Candidates are drawn without end for each episode (candidate ``i`` of episode ``e``
depends only on the key, ``e`` and ``i``); the simulation keeps the first valid ones.

Calibration (section IV). Frontal touches: the sensor faces straight down onto the shape (whose
top points up, +z), turned by a random angle about its normal, shifted so that the shape's axis
crosses the gel at a random offset from the image centre (uniform, up to
``max_offset_fraction`` of the field of view each way, in the sensor frame), and pressed to a
random depth in ``depth_range_mm``.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Float, Int, PRNGKeyArray

from tactojax import _struct as struct
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
class GraspsProtocol:
    """New grasps off the mapping grid, in episodes of a fixed object pose (a localization test set)."""

    episodes: int = 30
    grasps_per_episode: int = 5
    fingers: int = 1
    """1: the sensor jaw records (rigid opposite pad, as mapping); 2: both jaws carry a sensor."""
    yaw_range_deg: float = 20.0
    """Gripper yaw about world z, uniform within ±this, degrees."""
    turns_deg: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)
    """Object turns about world z an episode draws from (uniformly), degrees."""
    name: str = "grasps"


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
class GraspCandidates:
    """N candidate grasps of the new-grasps protocol, in the order they were asked for."""

    T_world_object: jaxlie.SE3
    """(N,) object poses (the episode's turn about world z)."""
    T_world_gripper: jaxlie.SE3
    """(N,) commanded gripper poses, fully open."""
    turn_rad: Float[Array, "N"]
    yaw_rad: Float[Array, "N"]
    u_mm: Float[Array, "N"]
    """Grasp centre along the gripper's x axis (horizontal), mm."""
    v_mm: Float[Array, "N"]
    """Grasp centre height (world z), mm."""
    episode: Int[Array, "N"]
    candidate: Int[Array, "N"]
    """Index of the candidate within its episode's sequence."""

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


def mapping_grid_for(obj: TactileObject, protocol: MappingProtocol, max_grasps: int) -> float:
    """The finest grid spacing, ``protocol.grid_mm`` or coarser in steps of 0.5 mm, whose mapping
    plan of ``obj`` has at most ``max_grasps`` grasps (before those that miss are dropped), mm."""
    if max_grasps < 1:
        raise ValueError(f"max_grasps must be positive, got {max_grasps}")
    grid = protocol.grid_mm
    while len(mapping_plan(obj, dataclasses.replace(protocol, grid_mm=grid)).yaw_rad) > max_grasps:
        grid += 0.5
    return grid


def grasps_plan(
    key: PRNGKeyArray, obj: TactileObject, protocol: GraspsProtocol = GraspsProtocol(),
    *, candidates: int | None = None, start: int = 0,
) -> GraspCandidates:
    """Candidates ``start .. start + candidates - 1`` of every episode (see the module docstring).

    Args:
        key: PRNG key of the protocol (the same key gives the same candidates).
        obj: the object.
        protocol: episodes, yaw range and turns.
        candidates: candidates per episode (default ``grasps_per_episode``).
        start: index of the first candidate of each episode.

    Returns:
        Episode-major candidates, (episodes * candidates,).
    """
    count = protocol.grasps_per_episode if candidates is None else candidates
    episode, candidate = np.divmod(np.arange(protocol.episodes * count), count)
    return grasp_candidates(key, obj, protocol, episode, start + candidate)


def grasp_candidates(
    key: PRNGKeyArray, obj: TactileObject, protocol: GraspsProtocol, episode, candidate, *, placement=None,
) -> GraspCandidates:
    """Candidate grasps ``candidate[n]`` of episodes ``episode[n]`` (integer arrays (N,)).

    ``placement[n]`` (default 0): the episode's how-manieth placement (turn) draw; an episode
    whose placement the gripper cannot grasp draws another (placement 0 is the one the
    protocol always drew)."""
    check_grasps_protocol(protocol)
    episode = np.asarray(episode, np.int64).reshape(-1)
    candidate = np.asarray(candidate, np.int64).reshape(-1)
    placement = np.zeros_like(episode) if placement is None else np.asarray(placement, np.int64).reshape(-1)
    if episode.size and (episode.min() < 0 or episode.max() >= protocol.episodes or candidate.min() < 0):
        raise ValueError(f"episodes must lie in [0, {protocol.episodes}) and candidates be >= 0")
    turn_keys, grasp_keys = _episode_keys(key, episode)
    draw_turn = jax.vmap(lambda k: jax.random.randint(k, (), 0, len(protocol.turns_deg)))
    redrawn = jax.vmap(jax.random.fold_in)(turn_keys, jnp.asarray(placement, jnp.uint32))
    turn_index = np.where(placement == 0, np.asarray(draw_turn(turn_keys)), np.asarray(draw_turn(redrawn)))
    draws = np.asarray(jax.vmap(lambda k, i: jax.random.uniform(jax.random.fold_in(k, i), (3,)))(
        grasp_keys, jnp.asarray(candidate, jnp.uint32)), np.float64).reshape(-1, 3)
    turn = np.deg2rad(np.asarray(protocol.turns_deg, np.float64))[np.asarray(turn_index)].reshape(-1)
    yaw = np.deg2rad(protocol.yaw_range_deg) * (2.0 * draws[:, 0] - 1.0)
    R_world_object = _rot_z_batch(turn)
    R_world_gripper = _rot_z_batch(yaw) @ _R_WORLD_GRIPPER_0
    # Box corners in the world, then in the yawed gripper axes: u along x, c along the closing axis.
    corners = np.einsum("nij,kj->nki", R_world_object, _box_corners(obj.bounds))
    u = np.einsum("nki,ni->nk", corners, R_world_gripper[:, :, 0])
    c = np.einsum("nki,ni->nk", corners, R_world_gripper[:, :, 1])
    z = corners[..., 2]
    grasp_u = u.min(1) + draws[:, 1] * (u.max(1) - u.min(1))
    grasp_v = z.min(1) + draws[:, 2] * (z.max(1) - z.min(1))
    centre_c = 0.5 * (c.min(1) + c.max(1))
    position = grasp_u[:, None] * R_world_gripper[:, :, 0] + centre_c[:, None] * R_world_gripper[:, :, 1]
    position[:, 2] = grasp_v
    return GraspCandidates(
        T_world_object=jaxlie.SE3.from_rotation(jaxlie.SO3.from_matrix(jnp.asarray(R_world_object, jnp.float32))),
        T_world_gripper=jaxlie.SE3.from_rotation_and_translation(
            jaxlie.SO3.from_matrix(jnp.asarray(R_world_gripper, jnp.float32)), jnp.asarray(position, jnp.float32)),
        turn_rad=jnp.asarray(turn, jnp.float32),
        yaw_rad=jnp.asarray(yaw, jnp.float32),
        u_mm=jnp.asarray(grasp_u, jnp.float32),
        v_mm=jnp.asarray(grasp_v, jnp.float32),
        episode=jnp.asarray(episode, jnp.int32),
        candidate=jnp.asarray(candidate, jnp.int32),
    )


def check_grasps_protocol(protocol: GraspsProtocol) -> None:
    """ValueError naming the first bad setting of a new-grasps protocol."""
    if protocol.episodes < 1 or protocol.grasps_per_episode < 1:
        raise ValueError(f"need at least one episode and one grasp per episode, got {protocol.episodes} "
                         f"episodes of {protocol.grasps_per_episode} grasps")
    if protocol.fingers not in (1, 2):
        raise ValueError(f"fingers must be 1 or 2, got {protocol.fingers}")
    if not 0.0 <= protocol.yaw_range_deg <= 90.0:
        raise ValueError(f"yaw range must lie in [0, 90] degrees, got {protocol.yaw_range_deg}")
    if not protocol.turns_deg:
        raise ValueError("need at least one object turn")


def _episode_keys(key: PRNGKeyArray, episode: np.ndarray) -> tuple[PRNGKeyArray, PRNGKeyArray]:
    """(turn key, grasp key) of each episode: functions of the protocol key and the episode only."""
    keys = jax.vmap(lambda e: jax.random.split(jax.random.fold_in(key, e)))(jnp.asarray(episode, jnp.uint32))
    return keys[:, 0], keys[:, 1]


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


def _rot_z_batch(angle: np.ndarray) -> np.ndarray:
    c, s, zero, one = np.cos(angle), np.sin(angle), np.zeros_like(angle), np.ones_like(angle)
    return np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1),
                     np.stack([zero, zero, one], -1)], -2)
