"""Recording touches to the dataset format, on a real or a simulated robot cell.

:class:`Recorder` appends synchronised touches (image, opening, gripper pose, timestamp) to a
dataset (:mod:`tactojax.io`'s format, the one ``tactojax map`` reads). Every touch is its own
chunk, written atomically before the manifest lists it, so a recording killed at any moment
(even SIGKILL) reads back every touch completed before the kill.

:func:`record_protocol` runs the mapping protocol (paper section V) on any
:class:`~tactojax.hardware.Robot`: for each planned grasp it moves, grasps, waits for a frame
taken after the jaws closed, pairs it with the opening and the pose (:func:`synchronise`) and
records it, then releases. :func:`record_grasps` is the passive variant for a robot driven by
other software: it records one touch each time the gripper reports a new hold.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import jaxlie
import numpy as np
from tqdm.auto import tqdm

from tactojax.geometry import opposite_sensor_pose, sensor_pose
from tactojax.hardware._camera import Camera
from tactojax.hardware._pose_source import PoseSource, StaleDataError
from tactojax.hardware._robot import Robot
from tactojax.hardware._sync import SynchronisedTouch, synchronise
from tactojax.io import DatasetWriter
from tactojax.sensor import SensorSpec
from tactojax.simulate import GraspPlan, sensor_metadata

MAX_SKEW_S = 0.05
"""Largest time between a frame and the opening and pose paired with it, s."""


def _identity_wxyz_xyz() -> np.ndarray:
    return np.array([1.0, 0, 0, 0, 0, 0, 0], np.float32)


class Recorder:
    """Appends touches to a dataset at ``path``, each durable as soon as :meth:`write` returns.

    Records hold ``image`` (H, W, 3) uint8, ``timestamp_s``, ``opening_mm``, ``T_world_gripper``,
    ``T_world_sensor`` (from the gripper kinematics), ``T_world_object`` (7,) wxyz + xyz mm
    (identity when the object's pose is not known: fixed in the world), ``object_id``, the
    grasp's index in its plan (-1 for passive recordings), and ``finger``: 0 for the sensor on
    the gripper's sensor jaw, 1 for a second sensor on the opposite jaw (its pose from
    :func:`~tactojax.geometry.opposite_sensor_pose`). Appending to an existing recording of the
    same sensor continues it (a recording made before the ``finger`` field holds first-finger
    touches only).

    Args:
        path: dataset directory.
        spec: the sensor (its name, image size and pixel pitch go into the metadata).
        source: free-form description of the devices (camera, gripper, pose source).
    """

    def __init__(self, path: str | os.PathLike, spec: SensorSpec, *, source: dict | None = None):
        self.spec = spec
        metadata = {
            "sensor": sensor_metadata(spec),
            "protocol": {"name": "recording"},
            "recording": source or {},
        }
        self._writer = DatasetWriter(path, metadata=metadata, chunk_size=1)

    def __len__(self) -> int:
        return len(self._writer)

    def write(self, touch: SynchronisedTouch, *, object_id: str, T_world_object: jaxlie.SE3 | None = None,
              plan_index: int = -1, finger: int = 0) -> None:
        """Append one touch (``finger`` 1: the opposite jaw's sensor, ``touch.image`` its frame);
        it is on disk (and listed) when this returns."""
        if touch.image.shape != (*self.spec.shape, 3) or touch.image.dtype != np.uint8:
            raise ValueError(f"a touch image must be {(*self.spec.shape, 3)} uint8, got {touch.image.shape} "
                             f"{touch.image.dtype}")
        if not (math.isfinite(touch.opening_mm) and touch.opening_mm > 0):
            raise ValueError(f"a touch needs a positive gripper opening, got {touch.opening_mm} mm")
        if finger not in (0, 1):
            raise ValueError(f"finger must be 0 (the sensor jaw) or 1 (the opposite jaw), got {finger}")
        schema = self._writer.schema
        with_finger = schema is None or "finger" in schema
        if finger == 1 and not with_finger:
            raise ValueError(f"the recording at {self._writer.path} predates the finger field: record both "
                             "fingers into a new recording")
        T_world_gripper = np.asarray(touch.T_world_gripper.wxyz_xyz, np.float32)
        kinematics = opposite_sensor_pose if finger == 1 else sensor_pose
        T_world_sensor = kinematics(jaxlie.SE3(T_world_gripper), np.float32(touch.opening_mm))
        record = {
            "image": touch.image,
            "timestamp_s": np.float64(touch.timestamp_s),
            "opening_mm": np.float32(touch.opening_mm),
            "T_world_gripper": T_world_gripper,
            "T_world_sensor": np.asarray(T_world_sensor.wxyz_xyz, np.float32),
            "T_world_object": (_identity_wxyz_xyz() if T_world_object is None
                               else np.asarray(T_world_object.wxyz_xyz, np.float32)),
            "object_id": np.str_(object_id),
            "plan_index": np.int64(plan_index),
        }
        if with_finger:
            record["finger"] = np.int64(finger)
        self._writer.append(record)

    def close(self) -> None:
        self._writer.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


@dataclass
class RecordingSummary:
    """What a recording run did."""

    recorded: int = 0
    """Touches written."""
    missed: int = 0
    """Grasps that closed on nothing."""
    stale: int = 0
    """Touches dropped because a stream was stale (see ``StaleDataError``)."""


def frame_after(camera: Camera, time_s: float, *, max_frames: int = 300):
    """The first frame the camera took at or after ``time_s`` (camera clock), skipping older ones."""
    for _ in range(max_frames):
        frame = camera.read()
        if frame.timestamp_s >= time_s:
            return frame
    raise StaleDataError("camera", float("inf"), 0.0, f"no frame after {time_s:.3f} s in {max_frames} frames")


def wait_for_pose_after(poses: PoseSource, time_s: float, *, timeout_s: float) -> None:
    """For a live feed (one with ``latest``), wait until it holds a sample at or after ``time_s``.

    Without it a pose looked up at a frame's time could come from before the frame with nothing
    after it (the arm may have moved in between, e.g. the wrist settling as the jaws close).
    """
    if not hasattr(poses, "latest"):
        return
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            if poses.latest(max_age_s=float("inf")).timestamp_s >= time_s:
                return
        except StaleDataError:
            pass
        if time.monotonic() > deadline:
            raise StaleDataError("robot pose", timeout_s, timeout_s, f"no sample after the frame at {time_s:.4f} s")
        time.sleep(0.001)


def capture_touch(camera: Camera, read_opening: Callable[[], float], poses: PoseSource, *,
                  after_s: float, max_skew_s: float = MAX_SKEW_S, clock: Callable[[], float] = time.monotonic
                  ) -> SynchronisedTouch:
    """A frame taken after ``after_s``, paired with the opening read now and the pose at its time."""
    frame = frame_after(camera, after_s)
    opening = (clock(), read_opening())
    wait_for_pose_after(poses, frame.timestamp_s, timeout_s=max_skew_s)
    return synchronise(frame, lambda: opening, poses, max_skew_s=max_skew_s)


def record_protocol(
    robot: Robot,
    camera: Camera,
    read_opening: Callable[[], float],
    poses: PoseSource,
    plan: GraspPlan,
    recorder: Recorder,
    *,
    object_id: str,
    place_object: Callable[[jaxlie.SE3], None] | None = None,
    settle_s: float = 0.0,
    max_skew_s: float = MAX_SKEW_S,
    clock: Callable[[], float] = time.monotonic,
    progress: bool = True,
) -> RecordingSummary:
    """Run a mapping plan on a robot and record every grasp that closes on the object.

    Args:
        robot: the arm and gripper.
        camera: the tactile camera (frames stamped on ``clock``).
        read_opening: the gripper's current opening, mm (e.g. ``WSG50.opening_mm``).
        poses: the robot's ``T_world_gripper`` feed (stamped on ``clock``).
        plan: the grasps (:func:`tactojax.simulate.mapping_plan`).
        recorder: where touches go.
        object_id: the object's name in the records.
        place_object: called with the plan's object pose whenever it changes (the protocol's
            turns: an operator, a turntable, or the simulator places the object).
        settle_s: wait after the jaws close before the frame is taken, s.
        max_skew_s: largest frame-to-opening and frame-to-pose time difference, s.
        clock: the clock shared by the camera and the pose feed.
        progress: show a progress bar.
    """
    summary = RecordingSummary()
    object_poses = np.asarray(plan.T_world_object.wxyz_xyz)
    gripper_poses = np.asarray(plan.T_world_gripper.wxyz_xyz)
    placed = None
    for index in tqdm(range(len(plan)), desc=f"record {object_id}", unit="grasp", disable=not progress):
        if place_object is not None and (placed is None or not np.array_equal(placed, object_poses[index])):
            placed = object_poses[index]
            place_object(jaxlie.SE3(placed))
        robot.move_to(jaxlie.SE3(gripper_poses[index]))
        if robot.grasp() is None:
            summary.missed += 1
            robot.release()
            continue
        closed_s = clock() + settle_s
        try:
            touch = capture_touch(camera, read_opening, poses, after_s=closed_s, max_skew_s=max_skew_s, clock=clock)
        except StaleDataError as error:
            tqdm.write(f"grasp {index}: skipped, {error}")
            summary.stale += 1
        else:
            recorder.write(touch, object_id=object_id, T_world_object=jaxlie.SE3(object_poses[index]),
                           plan_index=index)
            summary.recorded += 1
        robot.release()
    return summary


def record_grasps(
    camera: Camera,
    gripper,
    poses: PoseSource,
    recorder: Recorder,
    *,
    object_id: str,
    touches: int | None = None,
    poll_s: float = 0.02,
    settle_s: float = 0.1,
    max_skew_s: float = MAX_SKEW_S,
    clock: Callable[[], float] = time.monotonic,
    progress: bool = True,
) -> RecordingSummary:
    """Record one touch per grasp while other software drives the robot (passive recording).

    Polls the gripper's grasping state; each time it starts holding a part, waits ``settle_s``,
    records a touch, and re-arms once the gripper lets go. Stops after ``touches`` touches
    (None: until interrupted).

    Args:
        gripper: a :class:`~tactojax.hardware.WSG50` (``grasping_state()``, ``opening_mm()``).
        Others: as :func:`record_protocol`.
    """
    from tactojax.hardware._wsg50_protocol import GraspingState

    summary = RecordingSummary()
    holding = False
    bar = tqdm(total=touches, desc=f"record {object_id}", unit="touch", disable=not progress)
    while touches is None or summary.recorded < touches:
        state = gripper.grasping_state()
        if state == GraspingState.HOLDING and not holding:
            holding = True
            try:
                touch = capture_touch(camera, gripper.opening_mm, poses, after_s=clock() + settle_s,
                                      max_skew_s=max_skew_s, clock=clock)
            except StaleDataError as error:
                tqdm.write(f"touch skipped: {error}")
                summary.stale += 1
                continue
            recorder.write(touch, object_id=object_id)
            summary.recorded += 1
            bar.update(1)
        elif state != GraspingState.HOLDING:
            holding = False
        time.sleep(poll_s)
    bar.close()
    return summary
