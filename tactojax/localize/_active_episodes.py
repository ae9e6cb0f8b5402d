"""Closed-loop active touch in simulation: which policy localizes with the fewest grasps.

Each episode places the object at a random turn (the new-grasps protocol's placement, all
turns allowed; drawn again, as the protocol does, where no grasp closes on it) and makes a
first grasp, the protocol's first that closes on it. Then each
policy chooses every further grasp and the simulator executes it at the object's true
placement (both fingers recorded; heightmaps predicted from the images by the shape model,
features by the encoder, as a robot would). A chosen grasp that misses or collides is spent,
and the belief learns from it (:func:`~tactojax.localize.active.observe_failed_grasp`).

Policies:

- ``active``: the best of ``candidates`` proposed grasps by expected gain
  (:func:`~tactojax.localize.active.next_grasp`);
- ``largest-contact``: of the same proposals, the one with the largest predicted contact at
  the belief's most likely pose;
- ``random``: the protocol's next grasp that closes on the object (the new-grasps test sets'
  sampler; the grasps it skips are not charged, as in those test sets).

After every grasp the error is the paper's (the RMSE between all fused touches' true contact
clouds at their true and estimated poses, and its symmetry-aware value), next to the belief's
P(within 2 mm).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from tqdm.auto import tqdm

from tactojax.geometry import heightmap_to_points, take
from tactojax.localize._active import ActiveSettings, next_grasp, observe_failed_grasp, propose_grasps
from tactojax.localize._belief import BeliefSettings, PoseBelief, empty_belief
from tactojax.localize._compile import top_level_jit
from tactojax.localize._evaluate import cloud_moments
from tactojax.localize._localize import jitted_update
from tactojax.localize._map import LocalizationMap, Touch
from tactojax.localize._new_grasps import _errors
from tactojax.localize._predict_touch import map_marching_grid
from tactojax.objects import TactileObject
from tactojax.sensor import SensorSpec
from tactojax.simulate import GraspsProtocol, simulate_two_sensor_grasps
from tactojax.simulate._protocols import grasp_candidates
from tactojax.simulate._run import MAX_PLACEMENTS

POLICIES = ("active", "random", "largest-contact")


@dataclass
class ActiveEpisodes:
    """Per policy: (E, K) errors and beliefs after each of K grasps, and the ranking times."""

    rmse: dict[str, np.ndarray]
    """RMSE over the fused touches' true clouds, mm."""
    symmetric_rmse: dict[str, np.ndarray]
    """The same up to the object's symmetries, mm."""
    probability: dict[str, np.ndarray]
    """The belief's P(within 2 mm)."""
    spent: dict[str, np.ndarray]
    """Whether grasp k missed (or collided) and taught nothing."""
    turn_deg: np.ndarray
    """(E,) the object's turn in each episode, degrees."""
    ranking_s: list[float]
    """Wall time of every ``next_grasp`` call (the first includes compilation), s."""


def run_active_episodes(
    key: jax.Array,
    view: LocalizationMap,
    obj: TactileObject,
    spec: SensorSpec,
    observe: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]],
    *,
    episodes: int,
    max_grasps: int,
    policies: Sequence[str] = POLICIES,
    candidates: int = 64,
    turns_deg: Sequence[float] = (0.0, 90.0, 180.0, 270.0),
    belief_settings: BeliefSettings = BeliefSettings(),
    settings: ActiveSettings = ActiveSettings(),
    progress: bool = False,
) -> ActiveEpisodes:
    """Run the closed loop (see the module docstring) for every policy.

    Args:
        key: PRNG key (placements, protocol grasps, proposals, sensor noise).
        view: the object's map.
        obj: the simulated object (its true shape: only the simulator reads it).
        spec: the map's sensor.
        observe: (N, H, W, 3) uint8 frames -> (heightmaps mm, masks, features): what the robot
            reads from its frames (shape model and encoder).
        episodes, max_grasps: E episodes of K grasps each.
        policies: names from ``POLICIES``.
        candidates: proposals per choice of the active and largest-contact policies.
        turns_deg: the object turns an episode draws from, degrees.
        belief_settings, settings: the belief update and the active choice.
        progress: a progress bar per policy.

    Returns:
        :class:`ActiveEpisodes`.
    """
    unknown = sorted(set(policies) - set(POLICIES))
    if unknown:
        raise ValueError(f"unknown policies {unknown}; choose from {', '.join(POLICIES)}")
    if belief_settings.max_touches < 2 * max_grasps:
        belief_settings = dataclasses.replace(belief_settings, max_touches=2 * max_grasps)
    grid = map_marching_grid(view)
    protocol = GraspsProtocol(episodes=episodes, grasps_per_episode=max_grasps, fingers=2, turns_deg=tuple(turns_deg))
    protocol_key, policy_key, noise_key = jax.random.split(key, 3)
    errors = top_level_jit(_errors)
    shape = (episodes, max_grasps)
    out = ActiveEpisodes(*({p: np.zeros(shape) for p in policies} for _ in range(3)),
                         {p: np.zeros(shape, bool) for p in policies}, np.zeros(episodes), [])
    for episode in range(episodes):
        executed, closing = _protocol_grasps(protocol_key, jax.random.fold_in(noise_key, episode), spec, obj, protocol,
                                             episode, max_grasps)
        T_world_object = executed.T_world_object
        out.turn_deg[episode] = executed.turn_deg
        for policy in policies:
            touches = []  # every fused touch's true sensor pose and contact cloud moments
            belief = empty_belief(view, belief_settings)
            for k in range(max_grasps):
                if k == 0 or policy == "random":
                    grasp = take(executed.grasps, closing[k]) if k < len(closing) else None
                else:
                    T_world_gripper = _choose(jax.random.fold_in(policy_key, episode * max_grasps + k), view, grid,
                                              belief, policy, candidates, settings, out.ranking_s)
                    grasp = _execute(jax.random.fold_in(noise_key, 1000 * episode + k), spec, obj, T_world_object,
                                     T_world_gripper)
                if grasp is None or not bool(grasp.valid):
                    out.spent[policy][episode, k] = True
                    if k > 0 and policy != "random":  # a chosen grasp that failed rules poses out
                        belief = observe_failed_grasp(view, grid, belief, T_world_gripper, settings)
                else:
                    belief, felt = _fuse_grasp(view, belief, grasp, observe, T_world_object, belief_settings)
                    touches += felt
                if touches:
                    rmse, symmetric = _belief_errors(errors, view, belief, T_world_object, touches, 2 * max_grasps)
                    out.rmse[policy][episode, k], out.symmetric_rmse[policy][episode, k] = rmse, symmetric
                    out.probability[policy][episode, k] = float(belief.probability_within())
                else:  # nothing felt yet: no estimate
                    out.rmse[policy][episode, k] = out.symmetric_rmse[policy][episode, k] = np.inf
        if progress:
            tqdm.write(f"episode {episode + 1}/{episodes} (turn {out.turn_deg[episode]:.0f} deg): "
                       + ", ".join(f"{p} {out.symmetric_rmse[p][episode, -1]:.2f} mm" for p in policies))
    return out


@dataclass
class _ProtocolGrasps:
    grasps: object
    """The simulated protocol candidates (a GraspResult of two-finger grasps)."""
    T_world_object: jaxlie.SE3
    turn_deg: float


def _protocol_grasps(protocol_key, noise_key, spec, obj, protocol, episode, wanted, *, block=32, blocks=8,
                     placements=MAX_PLACEMENTS):
    """The new-grasps protocol's candidates of one episode, simulated in blocks until ``wanted``
    close on the object (at most ``blocks`` blocks); and the indices of those that close. A
    placement where none of the first two blocks closes is drawn again (as the protocol does)."""
    for placement in range(placements):
        results, closing = [], np.zeros(0, int)
        for b in range(blocks):
            plan = grasp_candidates(protocol_key, obj, protocol, np.full(block, episode), b * block + np.arange(block),
                                    placement=np.full(block, placement))
            result = simulate_two_sensor_grasps(jax.random.fold_in(noise_key, b), spec, obj, plan.T_world_object,
                                                plan.T_world_gripper)
            results.append(result)
            closing = np.concatenate([closing, b * block + np.flatnonzero(np.asarray(result.valid))])
            if len(closing) >= wanted or (b == 1 and len(closing) == 0):
                break
        if len(closing):
            break
    grasps = jax.tree.map(lambda *x: jnp.concatenate(x), *results)
    return (_ProtocolGrasps(grasps, jax.tree.map(lambda x: x[0], plan.T_world_object),
                            float(np.rad2deg(plan.turn_rad[0]))), closing)


def _execute(key, spec, obj, T_world_object, T_world_gripper):
    """One grasp simulated at the object's true pose."""
    one = lambda T: jax.tree.map(lambda x: x[None], T)  # noqa: E731
    return take(simulate_two_sensor_grasps(key, spec, obj, T_world_object, one(T_world_gripper)), 0)


def _choose(key, view, grid, belief, policy, candidates, settings, ranking_s) -> jaxlie.SE3:
    """The commanded gripper pose the policy chooses from the proposals."""
    proposals, closes = propose_grasps(key, view, grid, belief, candidates, settings)
    start = time.perf_counter()
    ranking = jax.block_until_ready(next_grasp(view, grid, belief, proposals, settings))
    ranking_s.append(time.perf_counter() - start)
    if policy == "active":
        best = int(ranking.order[0])
    else:  # largest-contact
        best = int(np.argmax(np.where(np.asarray(closes), np.asarray(ranking.contact_area), -1.0)))
    return take(proposals, best)


def _fuse_grasp(view: LocalizationMap, belief: PoseBelief, grasp, observe, T_world_object: jaxlie.SE3,
                belief_settings: BeliefSettings) -> tuple[PoseBelief, list[tuple]]:
    """The belief after an executed grasp's two touches (sensor finger, then the other), read
    from its camera frames as the robot would (``observe``); and, per touch, the true sensor pose
    in the object frame and the first two moments of its true contact cloud (for the errors)."""
    frames = np.asarray(jnp.round(grasp.imprint.image * 255.0)).astype(np.uint8)  # as a dataset stores them
    heightmaps, masks, features = observe(frames)
    felt = []
    for finger in range(2):
        touch = Touch(heightmap=jnp.asarray(heightmaps[finger]), mask=jnp.asarray(masks[finger]),
                      feature=jnp.asarray(features[finger]),
                      opening=jnp.asarray(grasp.imprint.opening[finger], jnp.float32))
        T_world_sensor = jax.tree.map(lambda x: x[finger], grasp.imprint.T_world_sensor)
        belief = jitted_update(view, belief, touch, T_world_sensor, belief_settings)
        points = heightmap_to_points(grasp.imprint.heightmap[finger], view.mm_per_px).reshape(-1, 3)
        felt.append((T_world_object.inverse() @ T_world_sensor,
                     *cloud_moments(points, grasp.imprint.mask[finger].reshape(-1))))
    return belief, felt


def _belief_errors(errors, view: LocalizationMap, belief: PoseBelief, T_world_object: jaxlie.SE3,
                   touches: list[tuple], slots: int) -> tuple[float, float]:
    """The cloud RMSE (mm) of the fused touches at the belief's best pose against their true
    poses, and its symmetry-aware value; ``touches`` padded to ``slots`` (one program for all);
    +inf for a belief without an estimate (no touch with contact)."""
    if not bool(belief.has_estimate):
        return math.inf, math.inf
    pad = slots - len(touches)
    T_object_sensor, means, covariances = zip(*touches)
    T_true = jaxlie.SE3(jnp.stack([T.wxyz_xyz for T in T_object_sensor] + [jaxlie.SE3.identity().wxyz_xyz] * pad))
    T_estimate = belief.best @ belief.T_world_reference.inverse() @ T_world_object @ T_true
    mask = jnp.asarray([True] * len(touches) + [False] * pad)
    rmse, symmetric, _, _ = errors(T_true, T_estimate, jnp.stack(list(means) + [means[0]] * pad),
                                   jnp.stack(list(covariances) + [covariances[0]] * pad), mask,
                                   view.symmetries, view.symmetry_axis, view.symmetry_centre)
    return float(rmse), float(symmetric)
