"""Slip sequences: an object sliding and turning in a closed grasp, frame by frame (a tracking test set).

Each sequence starts from a new grasp (a candidate of :class:`GraspsProtocol`: the object turned
by one of ``turns_deg``, the gripper from above at its own yaw and centre). Then, frame after
frame, the object slips in the grasp: the gripper moves relative to the fixed object in the
plane of its fingers (its x axis and its approach axis z) and turns about its closing axis y,
the motions a grasped object makes when it slides or swings between the pads. Every frame is
a grasp of its own (the jaws close again, the wrist centres), so the opening follows the
object's width.

The motion is smooth: per-frame velocities (in-plane translation, mm, and rotation, radians)
follow a first-order autoregressive process with correlation ``smoothness`` from frame to
frame, scaled so that no frame moves by more than ``max_step_mm`` or turns by more than
``max_step_deg``. The gripper stays within ``max_offset_mm`` and ``max_turn_deg`` of where it
started (a velocity component that would leave is reversed), and where the next frame would
lose the object (a pad off an edge) the whole motion reverses (:class:`SlipWalk`), so every
frame of a sequence is a touch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray


@dataclass(frozen=True)
class SlipProtocol:
    """Slip sequences from new grasps (see the module docstring)."""

    sequences: int = 10
    frames: int = 200
    """Frames per sequence (the first is the grasp before any slip)."""
    max_step_mm: float = 0.5
    """Largest in-plane slide between two frames, mm."""
    max_step_deg: float = 1.0
    """Largest turn about the closing axis between two frames, degrees."""
    max_offset_mm: float = 15.0
    """Largest in-plane distance from the start (each of the two in-plane axes), mm."""
    max_turn_deg: float = 30.0
    """Largest turn from the start, degrees."""
    smoothness: float = 0.95
    """Frame-to-frame correlation of the slip velocity, in [0, 1)."""
    yaw_range_deg: float = 20.0
    """Start grasps: gripper yaw about world z, uniform within ±this, degrees."""
    turns_deg: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)
    """Start grasps: object turns about world z a sequence draws from, degrees."""
    name: str = "slip"


def check_slip_protocol(protocol: SlipProtocol) -> None:
    """ValueError naming the first bad setting of a slip protocol."""
    if protocol.sequences < 1 or protocol.frames < 1:
        raise ValueError(f"need at least one sequence of at least one frame, got {protocol.sequences} "
                         f"sequences of {protocol.frames} frames")
    if protocol.max_step_mm < 0 or protocol.max_step_deg < 0:
        raise ValueError("the largest slip per frame must be >= 0 mm and >= 0 degrees")
    if protocol.max_offset_mm < 0 or not 0 <= protocol.max_turn_deg <= 90:
        raise ValueError("need max_offset_mm >= 0 and max_turn_deg in [0, 90]")
    if not 0.0 <= protocol.smoothness < 1.0:
        raise ValueError(f"smoothness must lie in [0, 1), got {protocol.smoothness}")
    if not 0.0 <= protocol.yaw_range_deg <= 90.0:
        raise ValueError(f"yaw range must lie in [0, 90] degrees, got {protocol.yaw_range_deg}")
    if not protocol.turns_deg:
        raise ValueError("need at least one object turn")


class SlipWalk:
    """The slip of one sequence, frame by frame: gripper offsets from its start pose, in the start
    gripper's frame, x (mm), z (mm) and the turn about y (radians).

    :meth:`propose` draws the next frames without taking them; :meth:`take` keeps the first few
    and, where the next one lost the object, reverses the motion (the object bounces off the end
    of what the pads can hold). Deterministic for a key and the same sequence of calls.
    """

    def __init__(self, key: PRNGKeyArray, protocol: SlipProtocol):
        check_slip_protocol(protocol)
        self.protocol = protocol
        self._rng = np.random.default_rng(np.asarray(jax.random.key_data(key)).ravel().tolist())
        self._limits = np.array([protocol.max_step_mm, protocol.max_step_mm, math.radians(protocol.max_step_deg)])
        self._bounds = np.array([protocol.max_offset_mm, protocol.max_offset_mm, math.radians(protocol.max_turn_deg)])
        self.offsets = [np.zeros(3)]
        """Offsets of the frames taken so far (frame 0: the start, no slip)."""
        self._velocity = self._rng.standard_normal(3)
        self._draws = np.zeros((0, 3))

    def _step(self, offset: np.ndarray, velocity: np.ndarray, draw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rho = self.protocol.smoothness
        velocity = rho * velocity + math.sqrt(1.0 - rho**2) * draw
        # A unit-free velocity becomes a step within the limits (slide and turn limited apart).
        slide = velocity[:2] / max(1.0, float(np.linalg.norm(velocity[:2])))
        step = np.concatenate([slide, [np.clip(velocity[2], -1.0, 1.0)]]) * self._limits
        leaving = np.abs(offset + step) > self._bounds
        return offset + np.where(leaving, -step, step), np.where(leaving, -velocity, velocity)

    def propose(self, count: int) -> np.ndarray:
        """(count, 3) offsets of the next ``count`` frames, if the object stays in the grasp."""
        if len(self._draws) < count:
            self._draws = np.concatenate([self._draws, self._rng.standard_normal((count - len(self._draws), 3))])
        offset, velocity, proposed = self.offsets[-1], self._velocity, []
        for draw in self._draws[:count]:
            offset, velocity = self._step(offset, velocity, draw)
            proposed.append(offset)
        return np.array(proposed)

    def take(self, count: int, *, bounce: bool) -> None:
        """Keep the first ``count`` proposed frames; ``bounce``: the next one lost the object, so
        the slip reverses from there."""
        offset, velocity = self.offsets[-1], self._velocity
        for draw in self._draws[:count]:
            offset, velocity = self._step(offset, velocity, draw)
            self.offsets.append(offset)
        self._draws = self._draws[count:]
        self._velocity = -velocity if bounce else velocity
        if bounce:
            self._draws = self._draws[1:]  # the lost frame's draw is not reused


def slip_offsets(key: PRNGKeyArray, protocol: SlipProtocol) -> np.ndarray:
    """(frames, 3) offsets of a slip that never loses the object (:class:`SlipWalk`, no bounces)."""
    walk = SlipWalk(key, protocol)
    walk.propose(protocol.frames - 1)
    walk.take(protocol.frames - 1, bounce=False)
    return np.array(walk.offsets)


def slipped_grippers(T_world_gripper: jaxlie.SE3, offsets: Float[Array, "F 3"]) -> jaxlie.SE3:
    """(F,) gripper poses: the start pose moved by each frame's offsets (:func:`slip_offsets`)."""
    offsets = jnp.asarray(offsets, jnp.float32)
    zeros = jnp.zeros(offsets.shape[0])
    slip = jaxlie.SE3.from_rotation_and_translation(
        jaxlie.SO3.from_y_radians(offsets[:, 2]), jnp.stack([offsets[:, 0], zeros, offsets[:, 1]], axis=-1))
    return T_world_gripper @ slip
