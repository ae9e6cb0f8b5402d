"""The live loop's plumbing: each frame reaches the localizer with its opening and the gripper pose
at its time (:class:`PoseLookup`), stale poses are counted, and a run is summarised."""

import jaxlie
import numpy as np
import pytest

from tactojax.hardware import Camera, EndOfStream, Frame, LiveStatistics, PoseLog, live_estimates
from tactojax.hardware._live import PoseLookup


class ListCamera(Camera):
    """Frames at given times, then the end of the stream."""

    def __init__(self, times):
        self.frames = [Frame(image=np.full((4, 5, 3), i, np.uint8), timestamp_s=float(t), index=i)
                       for i, t in enumerate(times)]

    def read(self) -> Frame:
        if not self.frames:
            raise EndOfStream("done")
        return self.frames.pop(0)

    @property
    def dropped_frames(self) -> int:
        return 0


class RecordingLocalizer:
    """Stands for a Localizer: records what each call was given."""

    def __init__(self):
        self.calls, self.second = [], []

    def __call__(self, image, opening_mm, T_world_gripper=None, second_image=None):
        from tactojax.localize import LiveEstimate

        self.calls.append((int(image[0, 0, 0]), opening_mm, T_world_gripper))
        self.second.append(None if second_image is None else int(second_image[0, 0, 0]))
        return LiveEstimate(object_id=None, object_probabilities={}, T_object_sensor=None, T_world_object=None,
                            probability_within=0.0, modes=(), contact=True, grasps=0, updated=False,
                            latency_s=0.001 * (len(self.calls)))


def pose_at(x_mm: float) -> list[float]:
    return [1.0, 0.0, 0.0, 0.0, x_mm, 0.0, 0.0]


def test_each_frame_gets_the_gripper_pose_at_its_time():
    log = PoseLog(np.array([0.0, 1.0, 2.0]), np.array([pose_at(0.0), pose_at(10.0), pose_at(10.0)]))
    lookup = PoseLookup(log, max_skew_s=0.6)
    localizer = RecordingLocalizer()
    openings = iter([20.0, 21.0, 22.0, 23.0])
    # 0.5 s: halfway through the move; 2.0 s: a sample; 3.0 s: 1 s from the last sample (stale).
    out = list(live_estimates(ListCamera([0.0, 0.5, 2.0, 3.0]), localizer, lambda: next(openings),
                              gripper_pose=lookup))
    assert [frame.index for frame, _ in out] == [0, 1, 2, 3]
    assert [(image, opening) for image, opening, _ in localizer.calls] == [(0, 20.0), (1, 21.0), (2, 22.0),
                                                                          (3, 23.0)]
    poses = [T for _, _, T in localizer.calls]
    assert all(isinstance(T, jaxlie.SE3) for T in poses[:3]) and poses[3] is None
    np.testing.assert_allclose([np.asarray(T.translation())[0] for T in poses[:3]], [0.0, 5.0, 10.0], atol=1e-5)
    assert lookup.stale == 1 and "stale" in lookup.last_error and lookup.last is None
    statistics = LiveStatistics()
    for frame, estimate in out:
        statistics.add(frame, estimate)
    statistics.stale_poses = lookup.stale
    summary = statistics.summary()
    assert summary["frames"] == 4 and summary["stale_poses"] == 1
    assert summary["latency_ms"]["max"] == pytest.approx(4.0)


def test_without_a_pose_source_the_localizer_gets_no_pose():
    localizer = RecordingLocalizer()
    out = list(live_estimates(ListCamera([0.0, 0.1]), localizer, 30.0, max_frames=1))
    assert len(out) == 1 and localizer.calls == [(0, 30.0, None)]
    with pytest.raises(ValueError, match="max_skew_s"):
        PoseLookup(PoseLog(np.zeros(1), np.array([pose_at(0.0)])), max_skew_s=0.0)


def test_a_second_camera_is_read_in_step_and_passed_as_the_second_image():
    localizer = RecordingLocalizer()
    second = ListCamera([0.0, 0.1])
    for frame in second.frames:
        frame.image[...] += 10
    out = list(live_estimates(ListCamera([0.0, 0.1, 0.2]), localizer, 30.0, second_camera=second))
    assert len(out) == 2  # the second camera's stream ended first
    assert [image for image, _, _ in localizer.calls] == [0, 1] and localizer.second == [10, 11]
    alone = RecordingLocalizer()
    list(live_estimates(ListCamera([0.0]), alone, 30.0))
    assert alone.second == [None]


class FailingCamera(ListCamera):
    """Fails at its third read."""

    def read(self) -> Frame:
        if len(self.frames) == 1:
            raise RuntimeError("camera unplugged")
        return super().read()


def test_read_ahead_hands_every_frame_in_order_and_the_camera_error():
    localizer, second = RecordingLocalizer(), ListCamera([0.0, 0.1, 0.2, 0.3])
    for frame in second.frames:
        frame.image[...] += 10
    out = list(live_estimates(ListCamera([0.0, 0.1, 0.2, 0.3, 0.4]), localizer, 30.0, second_camera=second,
                              read_ahead=2))
    assert [frame.index for frame, _ in out] == [0, 1, 2, 3]  # the second camera ended first
    assert [image for image, _, _ in localizer.calls] == [0, 1, 2, 3] and localizer.second == [10, 11, 12, 13]
    with pytest.raises(RuntimeError, match="unplugged"):
        list(live_estimates(FailingCamera([0.0, 0.1, 0.2]), RecordingLocalizer(), 30.0, read_ahead=1))
    with pytest.raises(ValueError, match="choose one"):
        next(live_estimates(ListCamera([0.0]), RecordingLocalizer(), 30.0, read_ahead=1, latest_only=True))
