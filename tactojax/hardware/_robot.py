"""The robot interface the mapping protocol runs on.

A :class:`Robot` moves the gripper to a pose, grasps and releases; that is all the mapping
protocol (paper section V) asks of an arm. A real robot implements it with its own motion
stack plus a :class:`~tactojax.hardware.WSG50` (or any gripper);
:class:`~tactojax.hardware.SimulatedRobot` implements it on the simulator, so the same
recording code (:func:`~tactojax.hardware.record_protocol`) runs against both.

:func:`execute_grasp` runs one chosen grasp (e.g. :func:`~tactojax.localize.active.next_grasp`'s) on
any robot through those three calls: approach, grasp, release, retreat.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar, runtime_checkable

import jaxlie
import numpy as np

APPROACH_MM = 50.0
"""How far above a grasp (back along the gripper's approach axis) the arm approaches and
retreats, mm."""

Held = TypeVar("Held")


@runtime_checkable
class Robot(Protocol):
    """An arm with a parallel-jaw gripper, as the mapping protocol sees it (mm, world frame)."""

    def move_to(self, T_world_gripper: jaxlie.SE3) -> None:
        """Move the (open) gripper to ``T_world_gripper`` and return when it is there."""

    def grasp(self) -> float | None:
        """Close the jaws; the opening at contact in mm, or None when nothing was grasped."""

    def release(self) -> None:
        """Open the jaws fully."""


@dataclass(frozen=True)
class ExecutedGrasp(Generic[Held]):
    """What :func:`execute_grasp` did."""

    opening_mm: float | None
    """The opening at contact, mm; None when the jaws closed on nothing (a spent grasp)."""
    held: Held | None
    """What ``while_closed`` returned (None after a miss, or without it)."""


def approach_pose(T_world_gripper: jaxlie.SE3, distance_mm: float = APPROACH_MM) -> jaxlie.SE3:
    """The gripper pose ``distance_mm`` back along the approach axis (the gripper's z, which
    points from the palm towards the object) from ``T_world_gripper``, mm."""
    return T_world_gripper @ jaxlie.SE3.from_translation(np.array([0.0, 0.0, -distance_mm], np.float32))


def execute_grasp(robot: Robot, T_world_gripper: jaxlie.SE3, *,
                  while_closed: Callable[[float], Held] | None = None,
                  approach_mm: float = APPROACH_MM) -> ExecutedGrasp[Held]:
    """Execute one grasp: move the open gripper to the approach pose above it, down to
    ``T_world_gripper``, close the jaws, call ``while_closed(opening_mm)`` (e.g. read the
    tactile frames) if they closed on the object, release, and retreat to the approach pose.

    Args:
        robot: any :class:`Robot`.
        T_world_gripper: the commanded grasp pose (fully open), in the robot's world frame, mm
            (a candidate of :func:`~tactojax.localize.active.propose_grasps`).
        while_closed: called with the opening (mm) while the jaws hold the object.
        approach_mm: approach and retreat distance along the gripper's approach axis, mm.

    Returns:
        the :class:`ExecutedGrasp`: the opening (None: a miss) and what ``while_closed`` returned.
    """
    above = approach_pose(T_world_gripper, approach_mm)
    robot.move_to(above)
    robot.move_to(T_world_gripper)
    opening = robot.grasp()
    try:
        held = while_closed(opening) if opening is not None and while_closed is not None else None
    finally:
        robot.release()
        robot.move_to(above)
    return ExecutedGrasp(opening_mm=opening, held=held)
