"""Tactile camera: timestamped RGB frames from OpenCV, rectified to a ``SensorSpec``'s image grid.

A ``Frame`` holds an RGB uint8 (H, W, 3) image on the spec's grid, the time it was taken and
its place on the camera's nominal frame grid. ``OpenCVCamera`` reads a device index, a video
file or a stream URL through ``cv2.VideoCapture``:

* Timestamps: a file's frames carry their container presentation times (seconds from the first
  frame); a live device or stream is stamped with the host's monotonic clock when the frame is
  grabbed, so that it can be paired with gripper and robot samples on the same clock.
* Dropped frames: OpenCV's frame counter counts decoded frames, so it cannot reveal a gap.
  Gaps are found in the timestamps instead: an interval longer than 1.5 nominal frame periods
  means ``round(interval / period) - 1`` frames were lost. They are counted in
  ``camera.dropped_frames`` and on the next frame (``frame.dropped_before``), and the frame's
  ``index`` skips them.
* Rectification: the four gel corners in the raw image define a homography onto the spec's
  (width_px, height_px) grid (``rectify_image``).
* ``write_video`` stores RGB frames losslessly (PNG frames in AVI, MKV or MOV; verified bit-exact
  with this OpenCV/FFmpeg build; FFV1 is too, but MJPG, mp4v, I420 and HFYU are not),
  optionally with gaps in the frame grid (MOV only) to reproduce recordings with dropped frames.
"""

from __future__ import annotations

import abc
import os
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Literal, Self

import cv2
import numpy as np
from jaxtyping import Float, UInt8

from tactojax import _struct as struct
from tactojax.sensor import SensorSpec

LOSSLESS_FOURCC = "png "
"""FourCC of the lossless codec used by ``write_video`` (FFmpeg's PNG encoder)."""
LOSSLESS_SUFFIXES = (".avi", ".mkv", ".mov")
"""Containers that hold ``LOSSLESS_FOURCC`` and read back bit-exact; only MOV keeps frame gaps."""
DROP_THRESHOLD_PERIODS = 1.5
"""A timestamp interval above this many nominal frame periods counts as dropped frames."""


class CameraError(RuntimeError):
    """A camera source could not be opened or a frame could not be read."""


class EndOfStream(CameraError):
    """A video file or stream has no more frames."""


@struct.dataclass
class Frame:
    """One tactile camera frame on the sensor's image grid."""

    image: UInt8[np.ndarray, "H W 3"]
    """RGB image, uint8, rectified or resized to the spec's (height_px, width_px)."""
    timestamp_s: float
    """Container time (files) or host monotonic time (live sources), seconds."""
    index: int
    """Position on the nominal frame grid: 0 for the first frame, skipping dropped frames."""
    dropped_before: int = 0
    """Frames detected missing between the previous frame and this one."""


class Camera(abc.ABC):
    """A source of ``Frame``s; iterate it, or ``read()`` one frame at a time."""

    @abc.abstractmethod
    def read(self) -> Frame:
        """The next frame. Raises ``EndOfStream`` after the last one, ``CameraError`` on failure."""

    @property
    @abc.abstractmethod
    def dropped_frames(self) -> int:
        """Frames detected missing since the camera was opened."""

    def close(self) -> None:
        """Release the source; reading afterwards raises ``CameraError``."""

    def capture_background(
        self, count: int = 30, *, statistic: Literal["median", "mean"] = "median"
    ) -> Float[np.ndarray, "H W 3"]:
        """The no-contact reference image: per-pixel median or mean of the next ``count`` frames.

        The median ignores a transient touch or flicker in a minority of the frames; the mean
        averages the pixel noise down further on a static scene.

        Args:
            count: number of frames to read, >= 1.
            statistic: ``"median"`` or ``"mean"``.

        Returns:
            (H, W, 3) float32 RGB in [0, 1].
        """
        if count < 1:
            raise ValueError(f"background needs at least one frame, got count={count}")
        reducers = {"median": np.median, "mean": np.mean}
        if statistic not in reducers:
            raise ValueError(f"statistic must be 'median' or 'mean', got {statistic!r}")
        frames = np.stack([self.read().image for _ in range(count)])
        return (reducers[statistic](frames, axis=0) / 255.0).astype(np.float32)

    def __iter__(self) -> Iterator[Frame]:
        while True:
            try:
                yield self.read()
            except EndOfStream:
                return

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


class OpenCVCamera(Camera):
    """A tactile camera read through ``cv2.VideoCapture``: a device, a video file or a stream URL.

    Frames come out as RGB uint8 on the spec's (height_px, width_px) grid. With ``corners`` the
    gel area is rectified by a homography (see ``rectify_image``). Without them a frame of a
    different size is resized to the spec (INTER_AREA when shrinking, bilinear when enlarging),
    which requires the same aspect ratio within 1 %: a different one means the raw image holds
    more than the gel, and corners are needed.

    Args:
        source: device index (int), video file path, or stream URL (contains "://").
        spec: the sensor (only its height_px and width_px are used), or the output (H, W) in px.
        corners: (4, 2) gel corners in the raw image, (x, y) pixels, in the order top-left,
            top-right, bottom-right, bottom-left; or None.
        nominal_fps: frame rate for dropped-frame detection; defaults to the source's
            CAP_PROP_FPS. If neither is known (<= 0), dropped frames are not detected.
        timestamps: ``"container"`` (a file's presentation times), ``"host"`` (``clock()`` when
            OpenCV hands the frame over, so driver buffering adds latency), or ``"auto"``:
            container for files, host otherwise.
        time_offset_s: added to every timestamp: for a file, its first frame's time on the clock
            of the pose and gripper logs; for a live camera, minus its capture-to-delivery latency.
        clock: host clock for ``"host"`` timestamps, seconds.
        api_preference: OpenCV capture backend (``cv2.CAP_*``).
    """

    def __init__(
        self,
        source: int | str | os.PathLike,
        spec: SensorSpec | tuple[int, int],
        *,
        corners: Sequence[Sequence[float]] | np.ndarray | None = None,
        nominal_fps: float | None = None,
        timestamps: Literal["auto", "container", "host"] = "auto",
        time_offset_s: float = 0.0,
        clock: Callable[[], float] = time.monotonic,
        api_preference: int = cv2.CAP_ANY,
    ):
        if timestamps not in ("auto", "container", "host"):
            raise ValueError(f"timestamps must be 'auto', 'container' or 'host', got {timestamps!r}")
        self._output_shape = tuple(spec) if isinstance(spec, tuple) else (spec.height_px, spec.width_px)
        self._corners = None if corners is None else validate_corners(corners)
        self._homography = None if corners is None else _homography(self._corners, *self._output_shape)
        self._checked_raw_shape: tuple[int, int] | None = None
        self._capture, self._kind, self._name = _open_capture(source, api_preference)
        if timestamps == "auto":
            timestamps = "container" if self._kind == "file" else "host"
        self._timestamps = timestamps
        self._time_offset_s = float(time_offset_s)
        self._clock = clock
        fps = nominal_fps if nominal_fps is not None else self._capture.get(cv2.CAP_PROP_FPS)
        self.nominal_fps: float | None = float(fps) if np.isfinite(fps) and fps > 0 else None
        """Frame rate used to detect dropped frames, Hz; None when unknown."""
        self._frame_count = int(self._capture.get(cv2.CAP_PROP_FRAME_COUNT)) if self._kind == "file" else 0
        self._frames_read = 0
        self._dropped_frames = 0
        self._previous: Frame | None = None

    @property
    def dropped_frames(self) -> int:
        return self._dropped_frames

    def read(self) -> Frame:
        if self._capture is None:
            raise CameraError(f"{self._name} is closed")
        grabbed = self._capture.grab()
        host_time_s = self._clock()
        if not grabbed:
            raise self._grab_failure()
        decoded, raw = self._capture.retrieve()
        if not decoded or raw is None:
            raise CameraError(f"{self._name}: could not decode frame {self._frames_read}")
        if self._timestamps == "container":
            timestamp_s = self._capture.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
        else:
            timestamp_s = host_time_s
        timestamp_s += self._time_offset_s
        dropped = 0 if self._previous is None else self._count_missing(timestamp_s - self._previous.timestamp_s)
        index = 0 if self._previous is None else self._previous.index + 1 + dropped
        frame = Frame(image=self._to_spec(raw), timestamp_s=timestamp_s, index=index, dropped_before=dropped)
        self._frames_read += 1
        self._dropped_frames += dropped
        self._previous = frame
        return frame

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None

    def _count_missing(self, interval_s: float) -> int:
        if self.nominal_fps is None:
            return 0
        periods = interval_s * self.nominal_fps
        return max(1, round(periods) - 1) if periods > DROP_THRESHOLD_PERIODS else 0

    def _grab_failure(self) -> CameraError:
        if self._kind == "device":
            return CameraError(f"{self._name} stopped delivering frames after {self._frames_read}")
        message = f"{self._name} ended after {self._frames_read} frames"
        if 0 < self._frames_read < self._frame_count:
            message += f", but its container lists {self._frame_count} (truncated or corrupt file?)"
        return EndOfStream(message)

    def _to_spec(self, raw: np.ndarray) -> UInt8[np.ndarray, "H W 3"]:
        rgb = _to_rgb(raw)
        if self._homography is not None:
            if rgb.shape[:2] != self._checked_raw_shape:
                _check_corners_inside(self._corners, rgb.shape[:2])
                self._checked_raw_shape = rgb.shape[:2]
            return _warp(rgb, self._homography, self._output_shape)
        return _resize(rgb, self._output_shape)


def validate_corners(corners: Sequence[Sequence[float]] | np.ndarray) -> Float[np.ndarray, "4 2"]:
    """Check four gel corners: (x, y) pixels, distinct, a convex quad in TL, TR, BR, BL order.

    In image coordinates (y down) that order runs clockwise on screen.

    Returns:
        (4, 2) float64 corners. Raises ValueError naming the problem.
    """
    points = np.asarray(corners, dtype=np.float64)
    if points.shape != (4, 2):
        raise ValueError(f"corners must be 4 (x, y) points, shape (4, 2); got shape {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"corners must be finite, got {points.tolist()}")
    for i in range(4):
        for j in range(i + 1, 4):
            if np.linalg.norm(points[i] - points[j]) < 1.0:
                raise ValueError(f"corners {i} and {j} coincide (less than 1 px apart): {points.tolist()}")
    edges = np.roll(points, -1, axis=0) - points
    turns = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
    if np.all(turns < 0):
        raise ValueError("corners run counter-clockwise on screen; give them as top-left, top-right, "
                         f"bottom-right, bottom-left: {points.tolist()}")
    if not np.all(turns > 1e-9 * np.max(np.abs(edges)) ** 2):
        raise ValueError(f"corners do not form a convex quadrilateral (concave, crossed or collinear): "
                         f"{points.tolist()}")
    return points


def rectify_image(
    raw_rgb: UInt8[np.ndarray, "H_raw W_raw 3"], corners: Sequence[Sequence[float]] | np.ndarray, spec: SensorSpec
) -> UInt8[np.ndarray, "H W 3"]:
    """Warp the gel area of a raw camera image onto the spec's (height_px, width_px) grid.

    The corners are the gel's corners, which become the outer edges of the output image: pixel
    coordinates put the centre of the raw image's top-left pixel at (0, 0), and corner
    top-left maps to (-0.5, -0.5), bottom-right to (width_px - 0.5, height_px - 0.5).
    Resampling is bilinear (``cv2.getPerspectiveTransform`` + ``cv2.warpPerspective``).

    Args:
        raw_rgb: (H_raw, W_raw, 3) uint8 image.
        corners: (4, 2) (x, y) pixels in the raw image, top-left, top-right, bottom-right,
            bottom-left (see ``validate_corners``).
        spec: output grid.

    Returns:
        (height_px, width_px, 3) uint8 image.
    """
    points = validate_corners(corners)
    _check_corners_inside(points, raw_rgb.shape[:2])
    return _warp(raw_rgb, _homography(points, spec.height_px, spec.width_px), spec.shape)


def write_video(
    path: str | os.PathLike,
    frames_rgb: UInt8[np.ndarray, "N H W 3"] | Sequence[UInt8[np.ndarray, "H W 3"]],
    *,
    fps: float,
    frame_numbers: Sequence[int] | None = None,
) -> Path:
    """Write RGB frames to a lossless video (PNG frames); they read back bit-exact.

    Args:
        path: output file, suffix .avi, .mkv or .mov.
        frames_rgb: N frames, RGB uint8, all the same (H, W, 3).
        fps: nominal frame rate, Hz.
        frame_numbers: optional (N,) strictly increasing frame-grid positions: frame i is
            presented at ``frame_numbers[i] / fps`` s, so a jump leaves a gap of dropped
            frames. MOV only (AVI has no timestamps; OpenCV's MKV muxing ignores them).

    Returns:
        The path written.
    """
    path = Path(path)
    if path.suffix.lower() not in LOSSLESS_SUFFIXES:
        raise ValueError(f"lossless video needs one of {LOSSLESS_SUFFIXES}, got {path.name!r}")
    frames = _validated_frames(frames_rgb)
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if frame_numbers is None:
        _encode_png_video(path, frames, fps)
        return path
    numbers = np.asarray(frame_numbers)
    if path.suffix.lower() != ".mov":
        raise ValueError(f"frame_numbers (gaps in the frame grid) need a .mov file, got {path.name!r}")
    if numbers.shape != (len(frames),) or not np.issubdtype(numbers.dtype, np.integer):
        raise ValueError(f"frame_numbers must be {len(frames)} integers, got {numbers!r}")
    if numbers[0] < 0 or np.any(np.diff(numbers) <= 0):
        raise ValueError(f"frame_numbers must be non-negative and strictly increasing, got {numbers.tolist()}")
    with tempfile.TemporaryDirectory() as scratch:
        encoded = Path(scratch) / "frames.avi"
        _encode_png_video(encoded, frames, fps)
        _remux_with_frame_numbers(encoded, path, numbers, fps, frames.shape[1:3])
    return path


def _open_capture(source: int | str | os.PathLike, api_preference: int) -> tuple[cv2.VideoCapture, str, str]:
    """(capture, kind in {"device", "file", "stream"}, a name for messages)."""
    if isinstance(source, (int, np.integer)) and not isinstance(source, bool):
        kind, name, target = "device", f"camera device {int(source)}", int(source)
    elif isinstance(source, (str, os.PathLike)) and "://" in os.fspath(source):
        kind, name, target = "stream", f"video stream {os.fspath(source)!r}", os.fspath(source)
    elif isinstance(source, (str, os.PathLike)):
        kind, name, target = "file", f"video file {os.fspath(source)!r}", os.fspath(source)
        if not Path(target).is_file():
            raise CameraError(f"{name} does not exist")
    else:
        raise TypeError(f"camera source must be a device index, a file path or a URL, got {source!r}")
    capture = cv2.VideoCapture(target, api_preference)
    if not capture.isOpened():
        capture.release()
        raise CameraError(f"could not open {name} (not a video, or no such device/stream)")
    return capture, kind, name


def _to_rgb(raw: np.ndarray) -> UInt8[np.ndarray, "H W 3"]:
    if raw.dtype != np.uint8:
        raise CameraError(f"camera delivered {raw.dtype} frames; expected 8-bit images")
    if raw.ndim == 2:
        return cv2.cvtColor(raw, cv2.COLOR_GRAY2RGB)
    if raw.ndim == 3 and raw.shape[2] == 4:
        return cv2.cvtColor(raw, cv2.COLOR_BGRA2RGB)
    if raw.ndim == 3 and raw.shape[2] == 3:
        return cv2.cvtColor(raw, cv2.COLOR_BGR2RGB)
    raise CameraError(f"camera delivered frames of shape {raw.shape}; expected (H, W) or (H, W, 3 or 4)")


def _homography(corners: Float[np.ndarray, "4 2"], height_px: int, width_px: int) -> Float[np.ndarray, "3 3"]:
    """Homography from raw pixels to output pixels, both with pixel centres at integers."""
    edges = np.array([[-0.5, -0.5], [width_px - 0.5, -0.5], [width_px - 0.5, height_px - 0.5],
                      [-0.5, height_px - 0.5]], dtype=np.float32)
    return cv2.getPerspectiveTransform(corners.astype(np.float32), edges)


def _check_corners_inside(corners: Float[np.ndarray, "4 2"], raw_shape: tuple[int, int]) -> None:
    height, width = raw_shape
    for x, y in corners:
        if not (-1.0 <= x <= width and -1.0 <= y <= height):
            raise ValueError(f"gel corner ({x:g}, {y:g}) lies outside the {width} x {height} px raw frame")


def _warp(rgb: np.ndarray, homography: np.ndarray, output_shape: tuple[int, int]) -> np.ndarray:
    height, width = output_shape
    return cv2.warpPerspective(rgb, homography, (width, height), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REPLICATE)


def _resize(rgb: np.ndarray, output_shape: tuple[int, int]) -> np.ndarray:
    height, width = output_shape
    if rgb.shape[:2] == output_shape:
        return rgb
    raw_aspect, aspect = rgb.shape[1] / rgb.shape[0], width / height
    if abs(raw_aspect / aspect - 1) > 0.01:
        raise ValueError(f"frame is {rgb.shape[1]} x {rgb.shape[0]} px (aspect {raw_aspect:.3f}) but the spec is "
                         f"{width} x {height} px (aspect {aspect:.3f}); pass the gel corners to rectify it")
    shrinking = rgb.shape[0] > height
    return cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)


def _validated_frames(frames_rgb) -> UInt8[np.ndarray, "N H W 3"]:
    if len(frames_rgb) == 0:
        raise ValueError("no frames to write")
    first = np.asarray(frames_rgb[0])
    for i, frame in enumerate(frames_rgb):
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"frame {i} must be RGB uint8 (H, W, 3), got {frame.dtype} {frame.shape}")
        if frame.shape != first.shape:
            raise ValueError(f"frame {i} has shape {frame.shape}, frame 0 has {first.shape}")
    return np.stack([np.asarray(frame) for frame in frames_rgb])


def _encode_png_video(path: Path, frames: np.ndarray, fps: float) -> None:
    height, width = frames.shape[1:3]
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*LOSSLESS_FOURCC), fps,
                             (width, height))
    if not writer.isOpened():
        raise CameraError(f"could not open a PNG video writer for {str(path)!r}")
    for frame in frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()


def _remux_with_frame_numbers(encoded: Path, path: Path, numbers: np.ndarray, fps: float,
                              shape: tuple[int, int]) -> None:
    """Copy the encoded PNG packets into a MOV, presenting packet i at frame ``numbers[i]``."""
    packets_in = cv2.VideoCapture(str(encoded), cv2.CAP_FFMPEG, [cv2.CAP_PROP_FORMAT, -1])
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*LOSSLESS_FOURCC), fps,
                             (shape[1], shape[0]),
                             [cv2.VIDEOWRITER_PROP_RAW_VIDEO, 1, cv2.VIDEOWRITER_PROP_KEY_INTERVAL, 1])
    if not packets_in.isOpened() or not writer.isOpened():
        raise CameraError(f"could not re-encapsulate PNG frames into {str(path)!r}")
    for number in numbers:
        read, packet = packets_in.read()
        if not read:
            raise CameraError(f"lost a frame while writing {str(path)!r}")
        writer.set(cv2.VIDEOWRITER_PROP_PTS, float(number))
        writer.write(packet)
    writer.release()
    packets_in.release()
