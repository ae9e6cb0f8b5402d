"""The live localization loop: camera frames, gripper openings and poses in, estimates out.

:func:`live_estimates` runs a compiled :class:`~tactojax.localize.Localizer` (or a
:class:`~tactojax.localize.Tracker`, which follows the pose between frames) on frames as they
come, each with the gripper's opening and, given a pose source (:class:`PoseLookup`), its pose
at the frame's time: the kinematics that let the belief fuse successive grasps of an object
that stays put. With ``latest_only`` (live cameras), a background thread keeps reading the
camera and the loop always takes the newest frame, so a slow step costs skipped frames instead
of a growing backlog (latency stays one step); without it (video files, benchmarks) every frame
is processed in order. :class:`LiveStatistics` summarises a run: sustained rate, latency
percentiles, skipped frames, stale poses and recompilations.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import jaxlie
import numpy as np

from tactojax.hardware._camera import Camera, EndOfStream, Frame
from tactojax.hardware._pose_source import PoseSource, StaleDataError
from tactojax.localize import LiveEstimate, Localizer, Tracker


class LatestFrame:
    """Reads a camera in a background thread and hands out only the newest frame.

    Args:
        camera: the frame source.
    """

    def __init__(self, camera: Camera):
        self.camera = camera
        self.skipped = 0
        """Frames read from the camera but never handed out (a newer one replaced them)."""
        self._frame: Frame | None = None
        self._error: BaseException | None = None
        self._fresh = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="tactojax-camera", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                frame = self.camera.read()
            except BaseException as error:  # handed to the consumer, who raises it
                with self._fresh:
                    self._error = error
                    self._fresh.notify_all()
                return
            with self._fresh:
                if self._frame is not None:
                    self.skipped += 1
                self._frame = frame
                self._fresh.notify_all()

    def get(self, timeout_s: float = 5.0) -> Frame:
        """The newest frame not handed out yet (waits for one); the camera's error once it fails."""
        with self._fresh:
            if not self._fresh.wait_for(lambda: self._frame is not None or self._error is not None, timeout_s):
                raise TimeoutError(f"no camera frame within {timeout_s} s")
            if self._frame is None:
                raise self._error
            frame, self._frame = self._frame, None
            return frame

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


class ReadAhead:
    """Reads a camera in a background thread, every frame in order, up to ``depth`` frames ahead
    of the loop: a camera whose read decodes (a video file, a compressed stream) then decodes
    while the localizer runs, where it would otherwise add its time to every frame's.

    Args:
        camera: the frame source.
        depth: frames read but not yet taken, at most (>= 1).
    """

    def __init__(self, camera: Camera, depth: int = 4):
        if depth < 1:
            raise ValueError(f"read-ahead depth must be >= 1, got {depth}")
        self.camera = camera
        self._frames: queue.Queue = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="tactojax-read-ahead", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                item = self.camera.read()
            except BaseException as error:  # handed to the consumer (EndOfStream included), who raises it
                item = error
            while not self._stop.is_set():
                try:
                    self._frames.put(item, timeout=0.1)
                    break
                except queue.Full:
                    continue
            if isinstance(item, BaseException):
                return

    def read(self, timeout_s: float = 5.0) -> Frame:
        """The next frame in order (waits for it); the camera's error where its stream failed or ended."""
        try:
            item = self._frames.get(timeout=timeout_s)
        except queue.Empty:
            raise TimeoutError(f"no camera frame within {timeout_s} s") from None
        if isinstance(item, BaseException):
            raise item
        return item

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


class PoseLookup:
    """The gripper pose at each frame's time, from a pose source (a robot's feed or a log).

    Called with a frame, it returns ``T_world_gripper`` at the frame's timestamp (the source's
    nearest sample within ``max_skew_s``, interpolated), or None when the source has none that
    close (the frame is then localized without kinematics, and counted in ``stale``).

    Args:
        poses: the source (:class:`~tactojax.hardware.PoseLog`, :class:`~tactojax.hardware.UdpPoseReceiver`),
            on the camera's clock.
        max_skew_s: largest time between a frame and the pose used for it, s.
    """

    def __init__(self, poses: PoseSource, *, max_skew_s: float = 0.05):
        if not max_skew_s > 0:
            raise ValueError(f"max_skew_s must be positive, got {max_skew_s}")
        self.poses, self.max_skew_s = poses, max_skew_s
        self.stale = 0
        """Frames for which the source had no pose within ``max_skew_s``."""
        self.last_error = ""
        """Why the latest stale lookup failed."""
        self.last: jaxlie.SE3 | None = None
        """The pose handed out for the latest frame (None when it was stale)."""

    def __call__(self, frame: Frame) -> jaxlie.SE3 | None:
        try:
            sample = self.poses.pose_at(frame.timestamp_s, max_skew_s=self.max_skew_s)
        except StaleDataError as error:
            self.stale += 1
            self.last_error, self.last = str(error), None
            return None
        self.last = jaxlie.SE3(np.asarray(sample.T_world_gripper.wxyz_xyz, np.float32))
        return self.last


def live_estimates(
    camera: Camera,
    localizer: Localizer | Tracker,
    opening_mm: float | Callable[[], float],
    *,
    gripper_pose: Callable[[Frame], jaxlie.SE3 | None] | None = None,
    second_camera: Camera | None = None,
    max_frames: int | None = None,
    latest_only: bool = False,
    read_ahead: int = 0,
) -> Iterator[tuple[Frame, LiveEstimate]]:
    """Localize every frame (or the newest one each time) as the camera delivers it.

    Args:
        camera: the tactile camera (rectified frames of the localizer's image size).
        localizer: the compiled localizer, or a tracker.
        opening_mm: the gripper opening, mm: a number, or a function read once per frame
            (e.g. ``gripper.opening_mm``).
        gripper_pose: the gripper pose at a frame (e.g. a :class:`PoseLookup`), passed to the
            localizer with it so that successive grasps fuse into one belief; None: no poses
            (each settled grasp then starts a new belief).
        second_camera: the opposite finger's tactile camera, when it carries a sensor: read in
            step with ``camera`` (one frame each per estimate), its frame goes to the localizer
            as ``second_image``; the stream ends when either does.
        max_frames: stop after this many estimates (None: until the stream ends).
        latest_only: read the camera in a background thread and always take the newest frame.
        read_ahead: read each camera (the second one too) up to this many frames ahead in a
            background thread (:class:`ReadAhead`), every frame still processed in order: the
            frames' decoding overlaps the localizer. 0: read in the loop. Without
            ``latest_only`` only.

    Yields:
        (frame, estimate) pairs.
    """
    if latest_only and read_ahead:
        raise ValueError("latest_only takes the newest frame, read_ahead every frame in order: choose one")
    read_opening = opening_mm if callable(opening_mm) else (lambda: float(opening_mm))
    readers = []
    if latest_only:
        readers.append(LatestFrame(camera))
        read_frame = readers[-1].get
    elif read_ahead:
        readers.append(ReadAhead(camera, read_ahead))
        read_frame = readers[-1].read
    else:
        read_frame = camera.read
    read_second = None if second_camera is None else second_camera.read
    if second_camera is not None and read_ahead:
        readers.append(ReadAhead(second_camera, read_ahead))
        read_second = readers[-1].read
    count = 0
    try:
        while max_frames is None or count < max_frames:
            try:
                frame = read_frame()
                second = read_second().image if read_second is not None else None
            except EndOfStream:
                return
            T_world_gripper = gripper_pose(frame) if gripper_pose is not None else None
            yield frame, localizer(frame.image, read_opening(), T_world_gripper, second)
            count += 1
    finally:
        for reader in readers:
            reader.close()


@dataclass
class LiveStatistics:
    """Rate and latency of a live run (wall-clock, this process).

    Skipped frames are those the loop did not process (``latest_only`` took a newer one);
    dropped frames are those the camera itself lost (``Frame.dropped_before``); stale poses
    are frames localized without a gripper pose (:attr:`PoseLookup.stale`, set by the caller).
    """

    latencies_s: list[float] = field(default_factory=list)
    """Per-frame localizer latency, s."""
    started_s: float = field(default_factory=time.perf_counter)
    finished_s: float | None = None
    skipped_frames: int = 0
    dropped_frames: int = 0
    recompilations: int = 0
    stale_poses: int = 0

    _previous_index: int | None = None

    def add(self, frame: Frame, estimate: LiveEstimate) -> None:
        """Count one processed frame (gaps in the frame index are skipped or dropped frames)."""
        self.latencies_s.append(estimate.latency_s)
        self.finished_s = time.perf_counter()
        self.dropped_frames += frame.dropped_before
        if self._previous_index is not None:
            self.skipped_frames += max(frame.index - self._previous_index - 1 - frame.dropped_before, 0)
        self._previous_index = frame.index

    def summary(self) -> dict:
        """Frames, sustained rate (Hz), latency percentiles (ms), skipped/dropped, stale poses,
        recompilations."""
        frames = len(self.latencies_s)
        elapsed = (self.finished_s or time.perf_counter()) - self.started_s
        latency_ms = 1e3 * np.asarray(self.latencies_s) if frames else np.zeros(1)
        return {"frames": frames, "seconds": elapsed, "rate_hz": frames / elapsed if elapsed > 0 else 0.0,
                "latency_ms": {"median": float(np.median(latency_ms)), "p95": float(np.percentile(latency_ms, 95)),
                               "max": float(latency_ms.max())},
                "skipped_frames": self.skipped_frames, "dropped_frames": self.dropped_frames,
                "stale_poses": self.stale_poses, "recompilations": self.recompilations}
