"""``localize``: the library's answer to "where is the object?", from one touch or many.

Every entry point (this function, the live :class:`~tactojax.localize.Localizer`, the
evaluations, the command line) runs the same pose belief (:mod:`tactojax.localize._belief`):
each touch updates it once, touches of an object that stays put related by their sensor poses
(the robot's kinematics: several grasps, both fingers of a grasp).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Int

from tactojax.localize._belief import BeliefSettings, PoseBelief, empty_belief, update_belief
from tactojax.localize._compile import top_level_jit
from tactojax.localize._map import LocalizationMap, Touch, _strong, canonical_touch


@functools.partial(top_level_jit, static_argnames=("settings",))
def update_program(view, belief, touch, T_world_sensor, exclude, settings):
    """The one compiled per-touch update (positional ``exclude``): :func:`jitted_update`, the live
    :class:`~tactojax.localize.Localizer` and the active episodes all run it, so that a process
    compiles it once per map shape and settings."""
    return update_belief(view, belief, touch, T_world_sensor, settings, exclude=exclude)


def jitted_update(view: LocalizationMap, belief: PoseBelief, touch: Touch, T_world_sensor: jaxlie.SE3,
                  settings: BeliefSettings = BeliefSettings(), *, exclude: int | jax.Array = -1) -> PoseBelief:
    """:func:`~tactojax.localize.update_belief`, jitted once per map and settings (strongly typed
    inputs, so that repeated calls never recompile)."""
    exclude = exclude.astype(jnp.int32) if isinstance(exclude, jax.Array) else np.int32(exclude)
    T_world_sensor = jaxlie.SE3(jnp.asarray(T_world_sensor.wxyz_xyz, jnp.float32))
    # Strong types: an updated belief has them, and a weakly typed one would compile apart.
    belief = jax.tree.map(_strong, belief)
    return update_program(view, belief, canonical_touch(touch), T_world_sensor, exclude, settings)


def check_touch(view: LocalizationMap, touch: Touch, name: str = "the touch") -> None:
    """A ValueError naming what is wrong with a touch for this map (shape, NaN, features)."""
    heightmap, mask = np.asarray(touch.heightmap), np.asarray(touch.mask)
    if heightmap.shape != view.packed_heightmaps.shape[1:] or mask.shape != heightmap.shape:
        raise ValueError(f"{name} has a {heightmap.shape} heightmap and a {mask.shape} mask; the map's imprints are "
                         f"{tuple(view.packed_heightmaps.shape[1:])} (the same sensor and shape model)")
    if np.shape(touch.feature) != (view.features.shape[1],):
        raise ValueError(f"{name} has {np.shape(touch.feature)} features; the map stores {view.features.shape[1]}-long "
                         "ones: encode it with the map's encoder")
    if not (np.all(np.isfinite(heightmap)) and np.all(np.isfinite(touch.feature)) and np.isfinite(touch.opening)):
        raise ValueError(f"{name} holds NaN or infinite values")


def localize(
    view: LocalizationMap,
    touches: Touch | Sequence[Touch],
    T_world_sensor: jaxlie.SE3 | Sequence[jaxlie.SE3] | None = None,
    *,
    belief: PoseBelief | None = None,
    settings: BeliefSettings = BeliefSettings(),
    exclude: int | Int[jax.Array, ""] = -1,
) -> PoseBelief:
    """The belief over where an object is, from one or several touches of it.

    Args:
        view: the object's map (:meth:`LocalizationMap.from_tactile_map`; build it once).
        touches: one touch, or several touches of the object while it stayed put (grasps, and
            both fingers of each).
        T_world_sensor: each touch's sensor pose in a fixed frame (the robot's base), mm: one
            pose, a sequence, or a batched ``jaxlie.SE3`` of as many poses as touches. May be
            left out for a single touch (the belief's world frame is then that sensor's).
        belief: a belief to continue (the touches so far); default: a new one.
        settings: the belief's parameters.
        exclude: a map imprint never used (leave-one-out), -1 for none.

    Returns:
        the :class:`~tactojax.localize.PoseBelief`: ``best`` (the first touch's sensor pose in
        the object frame), ``T_world_object``, ``probability_within(2.0)``, ``modes()``.

    Raises:
        ValueError: a touch does not fit the map, the poses do not match the touches, or no
            touch shows contact (there is nothing to localize).
    """
    touches = [touches] if isinstance(touches, Touch) else list(touches)
    if T_world_sensor is None:
        if len(touches) != 1:
            raise ValueError(f"{len(touches)} touches need their sensor poses (T_world_sensor), one per touch")
        poses = [jaxlie.SE3.identity()]
    elif isinstance(T_world_sensor, jaxlie.SE3):
        wxyz_xyz = np.asarray(T_world_sensor.wxyz_xyz, np.float32).reshape(-1, 7)
        poses = [jaxlie.SE3(row) for row in wxyz_xyz]
    else:
        poses = list(T_world_sensor)
    if len(poses) != len(touches):
        raise ValueError(f"{len(touches)} touches but {len(poses)} sensor poses: give one pose per touch")
    for i, (touch, pose) in enumerate(zip(touches, poses)):
        check_touch(view, touch, f"touch {i}")
        if not np.all(np.isfinite(np.asarray(pose.wxyz_xyz))):
            raise ValueError(f"the sensor pose of touch {i} holds NaN or infinite values")
    if belief is None and not any(np.any(np.asarray(t.mask)) for t in touches):
        raise ValueError("no touch shows contact (every mask is empty): there is nothing to localize")
    belief = empty_belief(view, settings) if belief is None else belief
    for touch, pose in zip(touches, poses):
        belief = jitted_update(view, belief, touch, pose, settings, exclude=exclude)
    return belief
