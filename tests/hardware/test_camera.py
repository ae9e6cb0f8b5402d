"""OpenCVCamera on real video files written with OpenCV: timestamps, rectification, drops, errors."""

import itertools

import cv2
import numpy as np
import pytest

from tactojax.hardware._camera import (
    CameraError,
    EndOfStream,
    OpenCVCamera,
    rectify_image,
    validate_corners,
    write_video,
)

FPS = 30.0


def _random_frames(count, height, width, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (count, height, width, 3), dtype=np.uint8)


@pytest.mark.parametrize("suffix", [".avi", ".mkv", ".mov"])
def test_lossless_round_trip_with_container_timestamps(tmp_path, small_spec, suffix):
    frames = _random_frames(5, *small_spec.shape)
    path = write_video(tmp_path / f"frames{suffix}", frames, fps=FPS)

    with OpenCVCamera(path, small_spec) as camera:
        read = [camera.read() for _ in range(5)]
        with pytest.raises(EndOfStream, match="ended after 5 frames"):
            camera.read()

    np.testing.assert_array_equal(np.stack([frame.image for frame in read]), frames)
    # MKV stores milliseconds, so timestamps are exact to 0.5 ms.
    np.testing.assert_allclose([frame.timestamp_s for frame in read], np.arange(5) / FPS, atol=5e-4)
    assert [frame.index for frame in read] == [0, 1, 2, 3, 4]
    assert [frame.dropped_before for frame in read] == [0] * 5
    assert camera.dropped_frames == 0


def test_dropped_frames_found_from_timestamp_gaps(tmp_path, small_spec):
    frames = _random_frames(6, *small_spec.shape, seed=1)
    frame_numbers = [0, 1, 2, 5, 6, 9]
    path = write_video(tmp_path / "gaps.mov", frames, fps=FPS, frame_numbers=frame_numbers)

    camera = OpenCVCamera(path, small_spec, time_offset_s=100.0)
    read = list(camera)

    np.testing.assert_array_equal(np.stack([frame.image for frame in read]), frames)
    np.testing.assert_allclose([frame.timestamp_s for frame in read], 100.0 + np.array(frame_numbers) / FPS,
                               atol=1e-6)
    assert [frame.dropped_before for frame in read] == [0, 0, 0, 2, 0, 2]
    assert [frame.index for frame in read] == frame_numbers
    assert camera.dropped_frames == 4


def test_host_clock_timestamps_and_gaps(tmp_path, small_spec):
    path = write_video(tmp_path / "frames.avi", _random_frames(5, *small_spec.shape), fps=FPS)
    # A live camera is stamped with the host clock when grabbed. Intervals of 1.4 periods are
    # jitter; 2 periods mean one frame was lost, 6 periods five.
    grid_positions = np.array([0.0, 1.0, 2.4, 4.4, 10.4])
    host_times = iter(10.0 + grid_positions / FPS)
    camera = OpenCVCamera(path, small_spec, timestamps="host", clock=lambda: next(host_times),
                          time_offset_s=-0.01)
    read = list(itertools.islice(camera, 5))

    np.testing.assert_allclose([frame.timestamp_s for frame in read], grid_positions / FPS + 9.99)
    assert [frame.dropped_before for frame in read] == [0, 0, 0, 1, 5]
    assert [frame.index for frame in read] == [0, 1, 2, 4, 10]
    assert camera.dropped_frames == 6


def _pattern(u, v, height, width):
    """A smooth RGB test pattern in [0, 1] at output pixel coordinates (u columns, v rows)."""
    return np.stack([0.5 + 0.35 * np.sin(2 * np.pi * u / width * 1.5) * np.cos(2 * np.pi * v / height),
                     0.2 + 0.6 * u / width,
                     0.8 - 0.6 * v / height], axis=-1)


def test_rectification_recovers_a_pattern_through_a_known_homography(tmp_path, small_spec):
    height, width = small_spec.shape
    raw_height, raw_width = 150, 200
    corners = np.array([[38.0, 24.0], [171.0, 12.0], [186.0, 131.0], [21.0, 140.0]])
    # Homography from output pixels to raw pixels, built independently of the camera code:
    # output pixel edges (-0.5, -0.5) ... (W - 0.5, H - 0.5) go to the gel corners.
    edges = np.array([[-0.5, -0.5], [width - 0.5, -0.5], [width - 0.5, height - 0.5], [-0.5, height - 0.5]])
    H_raw_output = cv2.findHomography(edges, corners)[0]
    # Render the raw frame analytically: each raw pixel samples the pattern where it maps to.
    x, y = np.meshgrid(np.arange(raw_width), np.arange(raw_height))
    mapped = np.linalg.inv(H_raw_output) @ np.stack([x.ravel(), y.ravel(), np.ones(x.size)])
    u, v = (mapped[:2] / mapped[2]).reshape(2, raw_height, raw_width)
    inside = (u >= -0.5) & (u <= width - 0.5) & (v >= -0.5) & (v <= height - 0.5)
    raw = np.where(inside[..., None], _pattern(u, v, height, width), 0.05)
    raw_frames = np.repeat(np.round(raw * 255).astype(np.uint8)[None], 2, axis=0)
    path = write_video(tmp_path / "raw.avi", raw_frames, fps=FPS)

    rectified = OpenCVCamera(path, small_spec, corners=corners).read().image

    columns, rows = np.meshgrid(np.arange(width), np.arange(height))
    expected = _pattern(columns, rows, height, width) * 255
    error = np.abs(rectified.astype(float) - expected)[1:-1, 1:-1]
    # Bilinear resampling of a smooth pattern plus two uint8 roundings: measured 0.30 mean,
    # 0.97 max grey levels; a half-pixel error in the corner convention gives 1.8 and 5.9.
    assert error.mean() < 0.6
    assert error.max() < 2.0
    np.testing.assert_array_equal(rectified, rectify_image(raw_frames[0], corners, small_spec))


def test_frames_of_another_size_are_resized_to_the_spec(tmp_path, small_spec):
    height, width = small_spec.shape
    frames = _random_frames(2, 2 * height, 2 * width, seed=2)
    path = write_video(tmp_path / "large.avi", frames, fps=FPS)

    image = OpenCVCamera(path, small_spec).read().image

    block_mean = frames[0].reshape(height, 2, width, 2, 3).astype(float).mean(axis=(1, 3))
    assert image.shape == (height, width, 3)
    assert np.abs(image - block_mean).max() <= 0.5 + 1e-9


def test_a_frame_of_another_aspect_ratio_needs_corners(tmp_path, small_spec):
    height = small_spec.height_px
    path = write_video(tmp_path / "square.avi", _random_frames(1, height, height), fps=FPS)
    with pytest.raises(ValueError, match="pass the gel corners"):
        OpenCVCamera(path, small_spec).read()


def test_background_is_the_per_pixel_median_or_mean(tmp_path, small_spec):
    rng = np.random.default_rng(3)
    base = rng.integers(60, 200, (*small_spec.shape, 3))
    frames = np.clip(base + rng.integers(-4, 5, (5, *base.shape)), 0, 255).astype(np.uint8)
    frames[2, 10:30, 20:50] = 255  # a touch in one frame: the median ignores it
    path = write_video(tmp_path / "background.avi", frames, fps=FPS)

    camera = OpenCVCamera(path, small_spec)
    median = camera.capture_background(5)
    camera = OpenCVCamera(path, small_spec)
    mean = camera.capture_background(5, statistic="mean")

    assert median.dtype == np.float32 and median.shape == (*small_spec.shape, 3)
    np.testing.assert_allclose(median, np.median(frames, axis=0) / 255, atol=1e-6)
    np.testing.assert_allclose(mean, frames.mean(axis=0) / 255, atol=1e-6)
    assert np.abs(median[10:30, 20:50] * 255 - base[10:30, 20:50]).max() <= 4
    with pytest.raises(ValueError, match="at least one frame"):
        camera.capture_background(0)


def test_a_corrupt_file_ends_early_with_a_hint(tmp_path, small_spec):
    path = write_video(tmp_path / "corrupt.avi", _random_frames(6, *small_spec.shape), fps=FPS)
    data = bytearray(path.read_bytes())
    fourth_png = [i for i in range(len(data)) if data[i:i + 4] == b"\x89PNG"][3]
    data[fourth_png:fourth_png + 8] = bytes(8)
    path.write_bytes(data)

    camera = OpenCVCamera(path, small_spec)
    assert len([camera.read() for _ in range(3)]) == 3
    with pytest.raises(EndOfStream, match="container lists 6"):
        camera.read()


def test_sources_that_cannot_be_opened(tmp_path, small_spec):
    with pytest.raises(CameraError, match="does not exist"):
        OpenCVCamera(tmp_path / "missing.avi", small_spec)
    not_a_video = tmp_path / "notes.avi"
    not_a_video.write_text("not a video")
    with pytest.raises(CameraError, match="could not open"):
        OpenCVCamera(not_a_video, small_spec)
    with pytest.raises(TypeError, match="device index"):
        OpenCVCamera(1.5, small_spec)
    camera = OpenCVCamera(write_video(tmp_path / "one.avi", _random_frames(1, *small_spec.shape), fps=FPS),
                          small_spec)
    camera.close()
    with pytest.raises(CameraError, match="closed"):
        camera.read()


@pytest.mark.parametrize(("corners", "message"), [
    ([[0, 0], [10, 0], [10, 10]], r"shape \(4, 2\)"),
    ([[0, 0], [10, 0], [10, 10], [np.nan, 10]], "finite"),
    ([[0, 0], [10, 0], [10, 0.5], [0, 10]], "corners 1 and 2 coincide"),
    ([[0, 0], [0, 10], [10, 10], [10, 0]], "counter-clockwise"),
    ([[0, 0], [10, 10], [10, 0], [0, 10]], "convex"),  # crossed (bow tie)
    ([[0, 0], [10, 0], [3, 3], [0, 10]], "convex"),  # concave
    ([[0, 0], [5, 0], [10, 0], [0, 10]], "convex"),  # three collinear
])
def test_bad_corners_are_rejected(corners, message):
    with pytest.raises(ValueError, match=message):
        validate_corners(corners)


def test_corners_outside_the_raw_frame_are_rejected(tmp_path, small_spec):
    path = write_video(tmp_path / "raw.avi", _random_frames(1, 100, 100), fps=FPS)
    corners = [[10, 10], [150, 10], [150, 90], [10, 90]]
    camera = OpenCVCamera(path, small_spec, corners=corners)
    with pytest.raises(ValueError, match=r"\(150, 10\) lies outside the 100 x 100"):
        camera.read()


def test_write_video_rejects_bad_frames(tmp_path):
    frames = _random_frames(2, 8, 8)
    with pytest.raises(ValueError, match="frame 1 has shape"):
        write_video(tmp_path / "a.avi", [frames[0], frames[1, :4]], fps=FPS)
    with pytest.raises(ValueError, match="frame 0 must be RGB uint8"):
        write_video(tmp_path / "a.avi", frames.astype(np.float32), fps=FPS)
    with pytest.raises(ValueError, match="frame 0 must be RGB uint8"):
        write_video(tmp_path / "a.avi", frames[..., :2], fps=FPS)
    with pytest.raises(ValueError, match="lossless video needs"):
        write_video(tmp_path / "a.mp4", frames, fps=FPS)
    with pytest.raises(ValueError, match="need a .mov"):
        write_video(tmp_path / "a.avi", frames, fps=FPS, frame_numbers=[0, 2])
    with pytest.raises(ValueError, match="strictly increasing"):
        write_video(tmp_path / "a.mov", frames, fps=FPS, frame_numbers=[3, 3])
