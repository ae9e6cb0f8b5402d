"""The robot interface the mapping protocol runs on.

A :class:`Robot` moves the gripper to a pose, grasps and releases; that is all the mapping
protocol (paper section V) asks of an arm. A real robot implements it with its own motion
stack plus a :class:`~tactojax.hardware.WSG50` (or any gripper);
:class:`~tactojax.hardware.SimulatedRobot` implements it on the simulator, so the same
recording code (:func:`~tactojax.hardware.record_protocol`) runs against both.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import jaxlie


@runtime_checkable
class Robot(Protocol):
    """An arm with a parallel-jaw gripper, as the mapping protocol sees it (mm, world frame)."""

    def move_to(self, T_world_gripper: jaxlie.SE3) -> None:
        """Move the (open) gripper to ``T_world_gripper`` and return when it is there."""

    def grasp(self) -> float | None:
        """Close the jaws; the opening at contact in mm, or None when nothing was grasped."""

    def release(self) -> None:
        """Open the jaws fully."""
