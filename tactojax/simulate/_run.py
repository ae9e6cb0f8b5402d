"""Run an exploration protocol in fixed-size batches, yielding imprint records."""

from __future__ import annotations

import functools
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
from tactojax.simulate._grasp import GraspConfig, simulate_grasps, simulate_two_sensor_grasps
from tactojax.simulate._protocols import (
    CalibrationProtocol, GraspCandidates, GraspPlan, GraspsProtocol, MappingProtocol, TouchPlan,
    calibration_plan, check_grasps_protocol, grasp_candidates, grasps_plan, mapping_plan,
)
from tactojax.simulate._slip import SlipProtocol, SlipWalk, check_slip_protocol, slipped_grippers
from tactojax.simulate._touch import touch

Records = dict[str, np.ndarray]
Protocol = MappingProtocol | CalibrationProtocol | GraspsProtocol | SlipProtocol

MAX_MISSES_IN_A_ROW = 50
"""New-grasps protocol: an episode gives up its placement after this many skipped candidates in
a row (it then starts again at another placement, the grasps it kept dropped)."""
MAX_PLACEMENTS = 8
"""New-grasps protocol: placements an episode draws before it gives up (an object longer than
the open gripper along the closing axis at some turns, e.g. the screwdriver at 90 degrees)."""


def plan_protocol(
    key: PRNGKeyArray, spec: SensorSpec, obj: TactileObject, protocol: Protocol,
) -> GraspPlan | TouchPlan | GraspCandidates:
    """The grasps (mapping), touches (calibration) or first candidate grasps (new grasps: as
    many per episode as it keeps; misses are replaced by later candidates) a protocol makes."""
    if isinstance(protocol, MappingProtocol):
        return mapping_plan(obj, protocol)
    if isinstance(protocol, GraspsProtocol):
        return grasps_plan(key, obj, protocol)
    if isinstance(protocol, SlipProtocol):
        raise ValueError("a slip protocol has no plan ahead of the simulation: its start grasps are the "
                         "first that keep touching (use simulate_protocol)")
    return calibration_plan(key, obj, spec, protocol)


def simulate_protocol(
    key: PRNGKeyArray,
    spec: SensorSpec,
    obj: TactileObject,
    protocol: Protocol,
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

    New grasps (:class:`GraspsProtocol`): every episode has exactly ``grasps_per_episode``
    grasps, the first valid candidates of its sequence (ValueError after
    ``MAX_MISSES_IN_A_ROW`` skipped candidates in a row); one record per finger imprint,
    ordered by episode, grasp, finger. ``episode`` counts 0 .. episodes - 1 here (see
    ``tactojax.simulate.simulate_to_dataset`` for datasets), ``grasp`` 0 .. grasps_per_episode - 1,
    ``finger`` 0 (sensor jaw) or 1 (opposite jaw, ``fingers=2``). Results are deterministic
    for a key and batch size.

    Slip sequences (:class:`~tactojax.simulate.SlipProtocol`): ``sequences`` runs of ``frames``
    consecutive frames each, ordered by ``sequence`` and ``frame``; a start grasp whose slip
    loses the object in any frame is replaced by the sequence's next candidate.
    """
    if isinstance(protocol, GraspsProtocol):
        yield from _simulate_new_grasps(key, spec, obj, protocol, config, batch_size, progress)
        return
    if isinstance(protocol, SlipProtocol):
        yield from _simulate_slip(key, spec, obj, protocol, config, batch_size, progress)
        return
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


def protocol_fields(protocol: Protocol) -> tuple[str, ...]:
    """Names of the per-record grasp parameters a protocol stores."""
    if isinstance(protocol, MappingProtocol):
        return ("turn_rad", "yaw_rad", "grid_u_mm", "grid_v_mm")
    if isinstance(protocol, GraspsProtocol):
        return ("episode", "grasp", "finger", "turn_rad", "yaw_rad")
    if isinstance(protocol, SlipProtocol):
        return ("sequence", "frame", "turn_rad", "yaw_rad")
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


def _simulate_new_grasps(key, spec, obj, protocol: GraspsProtocol, config, batch_size, progress
                         ) -> Iterator[Records]:
    """New-grasps protocol: blocks of episodes, simulated in full batches of candidates until
    each episode of the block has its grasps, then yielded in order."""
    plan_key, sim_key = jax.random.split(key)
    grasps = protocol.grasps_per_episode
    plan_candidates = functools.partial(grasp_candidates, plan_key, obj, protocol)
    check_grasps_protocol(protocol)
    block = max(1, batch_size // grasps)
    bar = tqdm(total=protocol.episodes * grasps, desc=f"{obj.name} ({protocol.name})", unit="grasp",
               disable=not progress)
    batch_index = 0
    for first in range(0, protocol.episodes, block):
        episodes = range(first, min(first + block, protocol.episodes))
        kept: dict[int, list[Records]] = {e: [] for e in episodes}
        next_candidate = dict.fromkeys(episodes, 0)
        misses = dict.fromkeys(episodes, 0)
        placement = dict.fromkeys(episodes, 0)
        while any(len(kept[e]) < grasps for e in episodes):
            lacking = {e: grasps - len(kept[e]) for e in episodes if len(kept[e]) < grasps}
            episode, candidate = _candidate_round(lacking, next_candidate, batch_size)
            for start in range(0, len(episode), batch_size):
                batch_episodes = episode[start:start + batch_size]
                batch_placements = np.array([placement[e] for e in batch_episodes.tolist()])
                batch = plan_candidates(batch_episodes, candidate[start:start + batch_size], placement=batch_placements)
                records, valid = _new_grasp_records(jax.random.fold_in(sim_key, batch_index), spec, obj, batch,
                                                    config, protocol.fingers)
                batch_index += 1
                for n, e in enumerate(np.asarray(batch.episode).tolist()):
                    if len(kept[e]) == grasps or batch_placements[n] != placement[e]:
                        continue  # done, or drawn at a placement the episode has given up
                    if not valid[n]:
                        misses[e] += 1
                        if misses[e] >= MAX_MISSES_IN_A_ROW and placement[e] + 1 < MAX_PLACEMENTS:
                            # The gripper can (almost) not grasp it so: start the episode again elsewhere.
                            placement[e], misses[e] = placement[e] + 1, 0
                            bar.update(-len(kept[e]))
                            kept[e] = []
                        elif misses[e] >= MAX_MISSES_IN_A_ROW:
                            bar.close()
                            raise ValueError(
                                f"{obj.name}: {misses[e]} grasps in a row missed the object or collided "
                                f"with it (episode {e}, placement {placement[e] + 1}); is it wider than the "
                                f"open gripper ({config.max_opening_mm} mm) or deeper than the gel?")
                        continue
                    misses[e] = 0
                    kept[e].append({name: values[n] for name, values in records.items()})
                    bar.update(1)
        for e in episodes:
            for g, grasp_records in enumerate(kept[e]):
                fingers = len(grasp_records["image"])
                grasp_records.update(episode=np.full(fingers, e, np.int64), grasp=np.full(fingers, g, np.int64),
                                     finger=np.arange(fingers, dtype=np.int64))
        yield {name: np.concatenate([r[name] for e in episodes for r in kept[e]]) for name in kept[first][0]}
    bar.close()


def _simulate_slip(key, spec, obj, protocol: SlipProtocol, config, batch_size, progress) -> Iterator[Records]:
    """Slip protocol: per sequence, the first start grasp (a new-grasps candidate) that touches;
    then batches of proposed frames, keeping each batch up to the first frame that lost the
    object and reversing the slip there (:class:`SlipWalk`). A start whose slip is stuck (every
    direction loses the object at once) is replaced by the sequence's next valid candidate."""
    check_slip_protocol(protocol)
    plan_key, slip_key, sim_key = jax.random.split(key, 3)
    starts = GraspsProtocol(episodes=protocol.sequences, grasps_per_episode=1, yaw_range_deg=protocol.yaw_range_deg,
                            turns_deg=protocol.turns_deg)
    bar = tqdm(total=protocol.sequences * protocol.frames, desc=f"{obj.name} ({protocol.name})", unit="frame",
               disable=not progress)
    calls = 0

    def frames_at(T_world_object, T_world_gripper):
        nonlocal calls
        calls += 1
        return simulate_grasps(jax.random.fold_in(sim_key, calls), spec, obj, T_world_object, T_world_gripper, config)

    def pick(tree, index):
        return jax.tree.map(lambda x: x[index], tree)

    for sequence in range(protocol.sequences):
        taken, attempt, candidate = None, 0, 0
        while taken is None:
            if attempt >= MAX_MISSES_IN_A_ROW:
                bar.close()
                raise ValueError(f"{obj.name}: {attempt} start grasps in a row missed the object or could not slip "
                                 f"without losing it (sequence {sequence}); lower max_offset_mm or max_step_mm")
            batch = grasp_candidates(plan_key, obj, starts, np.full(batch_size, sequence),
                                     candidate + np.arange(batch_size))
            candidate += batch_size
            T_world_object = pick(batch.T_world_object, 0)
            valid = np.asarray(frames_at(T_world_object, batch.T_world_gripper).valid)
            for index in np.flatnonzero(valid):
                attempt += 1
                start = pick(batch, index)
                taken = _slip_sequence(SlipWalk(jax.random.fold_in(jax.random.fold_in(slip_key, sequence), attempt),
                                                protocol), start, frames_at, batch_size, obj)
                if taken is not None:
                    break
            attempt += int(not valid.any()) * batch_size
        frames = protocol.frames
        records = taken
        records.update(sequence=np.full(frames, sequence, np.int64), frame=np.arange(frames, dtype=np.int64),
                       turn_rad=np.full(frames, float(start.turn_rad), np.float32),
                       yaw_rad=np.full(frames, float(start.yaw_rad), np.float32))
        bar.update(frames)
        yield records
    bar.close()


MAX_BOUNCES_IN_A_ROW = 8
"""Slip protocol: a start is abandoned when this many proposals in a row lose the object at once."""


def _slip_sequence(walk: SlipWalk, start: GraspCandidates, frames_at, batch_size: int, obj: TactileObject
                   ) -> Records | None:
    """The records of one slip sequence from ``start``, or None if its slip gets stuck."""
    frames = walk.protocol.frames
    T_world_object = start.T_world_object
    first = frames_at(T_world_object, jax.tree.map(lambda x: jnp.broadcast_to(x, (batch_size, *x.shape)),
                                                   start.T_world_gripper))
    parts = [(first, np.array([0]))]
    count, stuck = 1, 0
    while count < frames:
        proposed = walk.propose(batch_size)
        result = frames_at(T_world_object, slipped_grippers(start.T_world_gripper, proposed))
        valid = np.asarray(result.valid)
        keep = min(int(np.argmin(valid)) if not valid.all() else batch_size, frames - count)
        walk.take(keep, bounce=keep < batch_size and not valid[:keep + 1].all())
        stuck = stuck + 1 if keep == 0 else 0
        if stuck >= MAX_BOUNCES_IN_A_ROW:
            return None
        if keep:
            parts.append((result, np.arange(keep)))
            count += keep
    records = [_common(obj, r.imprint.image[i], r.imprint.heightmap[i], r.imprint.mask[i],
                       jax.tree.map(lambda x: x[i], r.imprint.T_world_sensor),
                       jax.tree.map(lambda x: x[i], r.imprint.T_world_gripper),
                       jaxlie.SE3(jnp.broadcast_to(T_world_object.wxyz_xyz, (len(i), 7))),
                       r.imprint.opening[i], r.depth_mm[i]) for r, i in parts]
    return {name: np.concatenate([r[name] for r in records]) for name in records[0]}


def _candidate_round(lacking: dict[int, int], next_candidate: dict[int, int], batch_size: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(episode, candidate) indices of one round: each episode's next candidates, as many as it
    lacks grasps, plus spares (round robin) that fill the last batch. Advances ``next_candidate``."""
    wanted = dict(lacking)
    for i in range(-sum(wanted.values()) % batch_size):
        wanted[list(wanted)[i % len(wanted)]] += 1
    episode = np.concatenate([np.full(n, e) for e, n in wanted.items()])
    candidate = np.concatenate([next_candidate[e] + np.arange(n) for e, n in wanted.items()])
    for e, n in wanted.items():
        next_candidate[e] += n
    return episode, candidate


def _new_grasp_records(key, spec, obj, plan: GraspCandidates, config: GraspConfig, fingers: int
                       ) -> tuple[Records, np.ndarray]:
    """Records of a batch of candidates, each field (B, fingers, ...), and their validity (B,)."""
    simulate = simulate_grasps if fingers == 1 else simulate_two_sensor_grasps
    result = simulate(key, spec, obj, plan.T_world_object, plan.T_world_gripper, config)
    imprint = result.imprint
    if fingers == 1:  # give every field a finger axis of 1
        imprint = jax.tree.map(lambda x: x[:, None], imprint)
    flat = jax.tree.map(lambda x: x.reshape(-1, *x.shape[2:]), imprint)
    count = plan.turn_rad.shape[0]

    def per_record(x):
        return jnp.repeat(x, fingers, axis=0)

    records = _common(obj, flat.image, flat.heightmap, flat.mask, flat.T_world_sensor, flat.T_world_gripper,
                      jax.tree.map(per_record, plan.T_world_object), flat.opening, per_record(result.depth_mm))
    records.update(turn_rad=per_record(plan.turn_rad), yaw_rad=per_record(plan.yaw_rad))
    records = {name: np.asarray(value).reshape(count, fingers, *np.shape(value)[1:])
               for name, value in records.items()}
    return records, np.asarray(result.valid)


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
