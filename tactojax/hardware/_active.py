"""An active episode on a robot: touch where the belief is least sure, until it is sure (issue 28).

:func:`active_episode` closes the loop of active touch on any :class:`~tactojax.hardware.Robot`
with tactile cameras and a pose feed (the simulated cell's or a real one's):

1. a first grasp (the caller's: e.g. where the object roughly is) is executed
   (:func:`~tactojax.hardware.execute_grasp`); while the jaws hold, a frame of each finger is
   taken after they closed and paired with the opening and the gripper pose at its time, and
   the live :class:`~tactojax.localize.Localizer` fuses the grasp into its beliefs
   (:meth:`~tactojax.localize.Localizer.fuse`);
2. from the belief of the most probable map, :func:`~tactojax.localize.active.propose_grasps` draws
   candidates where the map says the jaws close, :func:`~tactojax.localize.active.next_grasp` ranks
   them by expected gain in P(within 2 mm), and the robot executes the best;
3. until :func:`~tactojax.localize.active.should_stop` (P(within 2 mm) reached the threshold) or
   ``max_grasps`` grasps.

First grasps that miss are tried in turn and not charged (the object's pose is not known yet:
nothing is chosen), as ``tactojax eval-active`` does; a chosen grasp that misses or shows no
contact is spent, and every map's belief learns from it where the object is not
(:meth:`~tactojax.localize.Localizer.observe_failed_grasp`). Every program compiles at the first choice (the proposal and the ranking,
once per map, settings and candidate count) or when the localizer is built: the later grasps
of an episode, and later episodes, compile nothing.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import jax
import jaxlie
import numpy as np

from tactojax.geometry import take
from tactojax.hardware._camera import Camera
from tactojax.hardware._pose_source import PoseSource
from tactojax.hardware._recorder import MAX_SKEW_S, Recorder, capture_touch, frame_after
from tactojax.hardware._robot import APPROACH_MM, Robot, execute_grasp
from tactojax.hardware._sync import SynchronisedTouch
from tactojax.localize import LiveEstimate, Localizer, PoseBelief
from tactojax.localize.active import ActiveSettings, next_grasp, propose_grasps, should_stop


@dataclass(frozen=True)
class ActiveStep:
    """One executed grasp of an active episode."""

    grasp: int
    """Grasps charged so far, this one included (1-based; a first grasp that missed: 0)."""
    chosen: str
    """``"first"`` (the caller's) or ``"active"`` (the best by expected gain)."""
    T_world_gripper: jaxlie.SE3
    """The commanded grasp pose, in the robot's world frame, mm."""
    gain: float
    """Its expected gain in P(within 2 mm) (``settings.objective``'s unit; nan for a first grasp)."""
    opening_mm: float | None
    """The opening at contact, mm (None: the jaws closed on nothing)."""
    T_world_gripper_held: jaxlie.SE3 | None
    """Where the gripper held the object (the pose feed's at the frame): the commanded pose
    re-centred along the closing axis by the compliant wrist, mm (None after a miss)."""
    fused: bool
    """Whether the grasp's touches updated the belief (it closed and the frames showed contact)."""
    estimate: LiveEstimate | None
    """The localizer's estimate after the grasp (None before any fused grasp)."""
    belief: PoseBelief | None
    """The most probable map's belief after the grasp (None before any fused grasp)."""
    stop: bool
    """Whether the stopping rule fired: the episode ends here."""
    choice_s: float
    """Wall time of proposing and ranking the candidates, s (0 for a first grasp)."""


def active_episode(
    key: jax.Array,
    robot: Robot,
    localizer: Localizer,
    camera: Camera,
    read_opening: Callable[[], float],
    poses: PoseSource,
    first_grasps: jaxlie.SE3,
    *,
    second_camera: Camera | None = None,
    max_grasps: int = 3,
    candidates: int = 32,
    settings: ActiveSettings = ActiveSettings(),
    recorder: Recorder | None = None,
    object_id: str = "",
    settle_s: float = 0.0,
    max_skew_s: float = MAX_SKEW_S,
    approach_mm: float = APPROACH_MM,
    clock: Callable[[], float] = time.monotonic,
) -> Iterator[ActiveStep]:
    """Run one active episode (see the module docstring), yielding each grasp as it is fused.

    Args:
        key: PRNG key of the proposals.
        robot: the arm and gripper.
        localizer: the live localizer (its beliefs are reset first); its ``settings.max_touches``
            must hold every finger of ``max_grasps`` grasps.
        camera: the sensor finger's tactile camera (frames stamped on ``clock``).
        read_opening: the gripper's current opening, mm.
        poses: the robot's ``T_world_gripper`` feed (stamped on ``clock``).
        first_grasps: (N,) gripper poses for the first grasp, in the robot's world frame, mm,
            tried in order until one is fused.
        second_camera: the opposite finger's camera, if it carries a sensor (read in step).
        max_grasps: grasps charged at most (K).
        candidates: grasps proposed per choice.
        settings: proposal, ranking and stopping rule (``fingers`` as the gripper's sensors).
        recorder: if given, every fused grasp's touches are also recorded (both fingers when there
            is a second camera: ``finger`` 0 and 1).
        object_id: the object's name in the records.
        settle_s, max_skew_s, clock: as :func:`~tactojax.hardware.record_protocol`.
        approach_mm: approach and retreat distance (:func:`~tactojax.hardware.execute_grasp`).

    Yields:
        an :class:`ActiveStep` per executed grasp; the last one has ``stop`` set, or is the
        ``max_grasps``-th charged grasp, or the last first grasp that failed.
    """
    fingers = 1 if second_camera is None else 2
    if settings.fingers != fingers:
        raise ValueError(f"the cameras cover {fingers} finger(s) but settings.fingers is {settings.fingers}")
    if localizer.settings.max_touches < fingers * max_grasps:
        raise ValueError(f"the localizer's beliefs hold {localizer.settings.max_touches} touches, fewer than "
                         f"{fingers} fingers x {max_grasps} grasps: build it with BeliefSettings(max_touches=...)")
    first_grasps = jaxlie.SE3(np.asarray(first_grasps.wxyz_xyz, np.float32).reshape(-1, 7))

    def hold(opening_mm: float) -> tuple[SynchronisedTouch, np.ndarray | None]:
        touch = capture_touch(camera, read_opening, poses, after_s=clock() + settle_s, max_skew_s=max_skew_s,
                              clock=clock)
        second = None if second_camera is None else frame_after(second_camera, touch.timestamp_s).image
        return touch, second

    localizer.reset()
    charged, tried, estimate = 0, 0, None
    while charged < max_grasps:
        choice_s, gain = 0.0, math.nan
        if localizer.grasps == 0:
            if tried == len(first_grasps.wxyz_xyz):
                return
            chosen, T_world_gripper = "first", take(first_grasps, tried)
            tried += 1
        else:
            chosen, start = "active", time.perf_counter()
            m = _chosen_map(localizer, estimate)
            localizer.prepare_active(settings)  # the grids, and the program a failed grasp runs: compiled now
            view, grid, belief = localizer.stack.window(m), localizer.marching_grids().grid(m), localizer.beliefs[m]
            proposals, _ = propose_grasps(jax.random.fold_in(key, charged), view, grid, belief, candidates, settings)
            ranking = next_grasp(view, grid, belief, proposals, settings)
            best = int(ranking.order[0])
            T_world_gripper, gain = take(proposals, best), float(ranking.gain[best])
            choice_s = time.perf_counter() - start
        executed = execute_grasp(robot, T_world_gripper, while_closed=hold, approach_mm=approach_mm)
        before, held, second = localizer.grasps, None, None
        if executed.held is not None:
            touch, second = executed.held
            held = jaxlie.SE3(np.asarray(touch.T_world_gripper.wxyz_xyz, np.float32))
            estimate = localizer.fuse(touch.image, touch.opening_mm, touch.T_world_gripper, second)
        fused = localizer.grasps > before
        if chosen == "active" and not fused:  # the chosen grasp failed: the belief learns where the object is not
            localizer.observe_failed_grasp(T_world_gripper, settings)
        if fused and recorder is not None:
            recorder.write(touch, object_id=object_id)
            if second is not None:  # the opposite jaw's frame, with the same opening and gripper pose
                recorder.write(touch.replace(image=second), object_id=object_id, finger=1)
        charged += 1 if chosen == "active" or fused else 0
        belief = localizer.beliefs[_chosen_map(localizer, estimate)] if localizer.grasps else None
        stop = belief is not None and bool(should_stop(belief, settings.stop_probability))
        yield ActiveStep(grasp=charged, chosen=chosen, T_world_gripper=T_world_gripper, gain=gain,
                         opening_mm=executed.opening_mm, T_world_gripper_held=held, fused=fused, estimate=estimate,
                         belief=belief, stop=stop, choice_s=choice_s)
        if stop:
            return


def _chosen_map(localizer: Localizer, estimate: LiveEstimate | None) -> int:
    """The most probable map's index (the first while no map explains the touches)."""
    if estimate is None or estimate.object_id is None:
        return 0
    return localizer.object_ids.index(estimate.object_id)
