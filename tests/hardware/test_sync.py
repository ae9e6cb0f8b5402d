"""synchronise: a frame paired with the gripper opening and robot pose at its time, or StaleDataError."""

import numpy as np
import pytest

from tactojax.hardware._camera import Frame, OpenCVCamera, write_video
from tactojax.hardware._pose_source import PoseLog, StaleDataError
from tactojax.hardware._sync import opening_at, synchronise

POSES = PoseLog([10.0, 10.1, 10.2], [[1, 0, 0, 0, 0, 0, 0], [0, 1, 0, 0, 10, 0, 0], [0, 0, 1, 0, 20, 0, 0]])
OPENINGS = np.array([[10.0, 40.0], [10.05, 42.0], [10.1, 46.0]])


def _frame(timestamp_s):
    return Frame(image=np.zeros((4, 5, 3), np.uint8), timestamp_s=timestamp_s, index=0)


def test_pairs_a_frame_with_the_opening_and_pose_at_its_time():
    frame = _frame(10.025)
    touch = synchronise(frame, OPENINGS, POSES, max_skew_s=0.03)

    assert touch.image is frame.image
    assert touch.timestamp_s == 10.025
    assert touch.opening_mm == pytest.approx(41.0)  # halfway between 40 and 42 mm
    np.testing.assert_allclose(touch.T_world_gripper.wxyz_xyz,
                               POSES.pose_at(10.025, max_skew_s=0.03).T_world_gripper.wxyz_xyz)
    # A quarter of the way from identity to a half turn about x: 45 degrees about x, 2.5 mm.
    np.testing.assert_allclose(touch.T_world_gripper.wxyz_xyz,
                               [np.cos(np.pi / 8), np.sin(np.pi / 8), 0, 0, 2.5, 0, 0], atol=1e-12)
    nearest = synchronise(frame, OPENINGS, POSES, max_skew_s=0.03, interpolate=False)
    np.testing.assert_array_equal(nearest.T_world_gripper.wxyz_xyz, POSES.wxyz_xyz[0])


def test_stale_streams_are_named_with_their_skew():
    with pytest.raises(StaleDataError, match="gripper opening is stale") as error:
        synchronise(_frame(10.17), OPENINGS, POSES, max_skew_s=0.05)
    assert (error.value.stream, error.value.skew_s) == ("gripper opening", pytest.approx(0.07))

    with pytest.raises(StaleDataError, match="robot pose is stale") as error:
        synchronise(_frame(10.05), OPENINGS, POSES, max_skew_s=0.04)
    assert (error.value.stream, error.value.skew_s) == ("robot pose", pytest.approx(0.05))

    with pytest.raises(StaleDataError, match="gripper opening is stale: .* no samples"):
        synchronise(_frame(10.0), np.zeros((0, 2)), POSES, max_skew_s=0.05)


def test_opening_from_a_callable_driver():
    newest = (10.0, 33.5)
    assert opening_at(lambda: newest, 10.01, max_skew_s=0.02) == 33.5
    with pytest.raises(StaleDataError) as error:
        opening_at(lambda: newest, 10.1, max_skew_s=0.02)
    assert error.value.skew_s == pytest.approx(0.1)


def test_opening_samples_must_be_in_time_order():
    with pytest.raises(ValueError, match="increase strictly"):
        opening_at([(1.0, 40.0), (0.5, 41.0)], 0.7, max_skew_s=1.0)


def test_frames_from_a_video_pair_with_logs_on_the_recording_clock(tmp_path, small_spec):
    frames = np.random.default_rng(0).integers(0, 256, (4, *small_spec.shape, 3), dtype=np.uint8)
    # Frames at 10.0, 10.1, 10.2 (and 10.3 s, past the logs) on the logs' clock.
    path = write_video(tmp_path / "touches.avi", frames, fps=10.0)
    camera = OpenCVCamera(path, small_spec, time_offset_s=10.0)

    touches, stale = [], []
    for frame in camera:
        try:
            touches.append(synchronise(frame, OPENINGS, POSES, max_skew_s=0.11))
        except StaleDataError as error:
            stale.append((frame.index, error.stream))

    assert [touch.opening_mm for touch in touches] == pytest.approx([40.0, 46.0, 46.0])
    np.testing.assert_allclose(np.stack([touch.T_world_gripper.wxyz_xyz for touch in touches]), POSES.wxyz_xyz,
                               atol=1e-9)
    np.testing.assert_array_equal(np.stack([touch.image for touch in touches]), frames[:3])
    assert stale == [(3, "gripper opening")]
