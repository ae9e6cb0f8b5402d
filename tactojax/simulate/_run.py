"""Run an exploration protocol in fixed-size batches, yielding imprint records."""

from __future__ import annotations

from collections.abc import Iterator

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import PRNGKeyArray
from tqdm.auto import tqdm

from tactojax.geometry import gripper_pose
from tactojax.objects import TactileObject
from tactojax.sensor import SensorSpec
from tactojax.simulate._grasp import GraspConfig, simulate_grasps
from tactojax.simulate._protocols import (
    CalibrationProtocol, GraspPlan, MappingProtocol, TouchPlan, calibration_plan, mapping_plan,
)
from tactojax.simulate._touch import touch

Records = dict[str, np.ndarray]


def plan_protocol(
    key: PRNGKeyArray, spec: SensorSpec, obj: TactileObject,
    protocol: MappingProtocol | CalibrationProtocol,
) -> GraspPlan | TouchPlan:
    """The grasps (mapping) or touches (calibration) a protocol makes on ``obj``."""
    if isinstance(protocol, MappingProtocol):
        return mapping_plan(obj, protocol)
    return calibration_plan(key, obj, spec, protocol)


def simulate_protocol(
    key: PRNGKeyArray,
    spec: SensorSpec,
    obj: TactileObject,
    protocol: MappingProtocol | CalibrationProtocol,
    *,
    config: GraspConfig = GraspConfig(),
    batch_size: int = 16,
    progress: bool = True,
) -> Iterator[Records]:
    """Simulate a protocol on ``obj`` and yield its successful imprints, batch by batch.

    Every batch has the same size (the last one is padded), so the simulator compiles once.
    Yields dicts of numpy arrays with a leading record axis: ``image`` (uint8 RGB),
    ``heightmap`` (mm), ``mask``, ``T_world_sensor``/``T_world_gripper``/``T_world_object``
    (wxyz + xyz, mm), ``opening_mm``, ``depth_mm``, ``object_id`` and the protocol's own grasp
    parameters (see :func:`protocol_fields`). Skipped grasps (misses, collisions) are dropped.
    """
    plan_key, sim_key = jax.random.split(key)
    plan = plan_protocol(plan_key, spec, obj, protocol)
    total = len(plan)
    bar = tqdm(total=total, desc=f"{obj.name} ({protocol.name})", unit="grasp", disable=not progress)
    for start in range(0, total, batch_size):
        index = np.minimum(np.arange(start, start + batch_size), total - 1)
        batch = jax.tree.map(lambda x: x[index], plan)
        batch_key = jax.random.fold_in(sim_key, start)
        if isinstance(batch, GraspPlan):
            records, valid = _grasp_records(batch_key, spec, obj, batch, config)
        else:
            records, valid = _touch_records(batch_key, spec, obj, batch)
        keep = np.asarray(valid) & (np.arange(start, start + batch_size) < total)
        bar.update(int(min(batch_size, total - start)))
        if keep.any():
            yield {name: np.asarray(value)[keep] for name, value in records.items()}
    bar.close()


def protocol_fields(protocol: MappingProtocol | CalibrationProtocol) -> tuple[str, ...]:
    """Names of the per-record grasp parameters a protocol stores."""
    if isinstance(protocol, MappingProtocol):
        return ("turn_rad", "yaw_rad", "grid_u_mm", "grid_v_mm")
    return ("rotation_rad", "offset_x_mm", "offset_y_mm")


def _common(obj, image, heightmap, mask, T_ws, T_wg, T_wo, opening, depth) -> Records:
    count = image.shape[0]
    return {
        "image": np.asarray(jnp.round(image * 255.0)).astype(np.uint8),
        "heightmap": np.asarray(heightmap, np.float32),
        "mask": np.asarray(mask, bool),
        "T_world_sensor": np.asarray(T_ws.wxyz_xyz, np.float32),
        "T_world_gripper": np.asarray(T_wg.wxyz_xyz, np.float32),
        "T_world_object": np.asarray(T_wo.wxyz_xyz, np.float32),
        "opening_mm": np.asarray(opening, np.float32),
        "depth_mm": np.asarray(depth, np.float32),
        "object_id": np.array([obj.name] * count),
    }


def _grasp_records(key, spec, obj, plan: GraspPlan, config: GraspConfig) -> tuple[Records, np.ndarray]:
    # One object pose per simulate_grasps call: group the batch by turn (the plan is sorted by
    # turn, so a batch has at most a few groups).
    turns = np.asarray(plan.turn_rad)
    parts, valid = [], np.zeros(len(turns), bool)
    order = []
    for turn in np.unique(turns):
        index = np.nonzero(turns == turn)[0]
        padded = np.concatenate([index, np.full(len(turns) - len(index), index[-1])])
        sub = jax.tree.map(lambda x: x[padded], plan)
        T_world_object = jax.tree.map(lambda x: x[0], sub.T_world_object)
        result = simulate_grasps(jax.random.fold_in(key, int(index[0])), spec, obj, T_world_object,
                                 sub.T_world_gripper, config)
        result = jax.tree.map(lambda x: x[: len(index)], result)
        sub = jax.tree.map(lambda x: x[: len(index)], sub)
        imprint = result.imprint
        records = _common(obj, imprint.image, imprint.heightmap, imprint.mask, imprint.T_world_sensor,
                          imprint.T_world_gripper, sub.T_world_object, imprint.opening, result.depth_mm)
        records.update(turn_rad=sub.turn_rad, yaw_rad=sub.yaw_rad, grid_u_mm=sub.grid_u_mm,
                       grid_v_mm=sub.grid_v_mm)
        parts.append({k: np.asarray(v) for k, v in records.items()})
        valid[index] = np.asarray(result.valid)
        order.append(index)
    inverse = np.argsort(np.concatenate(order))
    merged = {k: np.concatenate([p[k] for p in parts])[inverse] for k in parts[0]}
    return merged, valid


def _touch_records(key, spec, obj, plan: TouchPlan) -> tuple[Records, np.ndarray]:
    contact, images, collides = touch(key, spec, obj, plan.T_world_sensor_start, plan.depth_mm,
                                      max_distance=plan_max_distance(obj))
    count = plan.depth_mm.shape[0]
    advance = jnp.stack([jnp.zeros(count), jnp.zeros(count), contact.travel], axis=-1)
    T_world_sensor = plan.T_world_sensor_start @ jaxlie.SE3.from_translation(advance)
    # A frontal touch has no second jaw: the gripper pose is the sensor finger's at opening 0.
    opening = jnp.zeros(count)
    valid = contact.touched & ~collides & (jnp.max(contact.rigid_heightmap, axis=(-2, -1)) < spec.gel_thickness_mm)
    records = _common(obj, images, contact.heightmap, contact.mask, T_world_sensor,
                      gripper_pose(T_world_sensor, opening), jaxlie.SE3.identity((count,)),
                      opening, plan.depth_mm)
    records.update(rotation_rad=plan.rotation_rad, offset_x_mm=plan.offset_x_mm, offset_y_mm=plan.offset_y_mm)
    return records, np.asarray(valid)


def plan_max_distance(obj: TactileObject) -> float:
    """How far a frontal touch looks down for the object, mm: its full height plus margin."""
    return float(obj.extents[2]) + 10.0
