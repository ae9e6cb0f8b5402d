"""Pair a tactile frame with the gripper opening and the robot pose at the frame's time.

All three streams must share one clock (the host's monotonic clock for live hardware, the
recording's clock for logs). Each stream's nearest sample must lie within ``max_skew_s`` of the
frame's timestamp, else ``StaleDataError`` names the stream and the skew. This module knows no
gripper driver: openings come as (timestamp_s, opening_mm) pairs or as a callable returning the
newest pair.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import jaxlie
import numpy as np
from jaxtyping import Float, UInt8

from tactojax import _struct as struct
from tactojax.hardware._pose_source import PoseSource, StaleDataError

OpeningSamples = Float[np.ndarray, "N 2"] | Sequence[tuple[float, float]] | Callable[[], tuple[float, float]]
"""Gripper openings: (N, 2) rows of (timestamp_s, opening_mm) with increasing times, or a
callable returning the newest (timestamp_s, opening_mm)."""


class TimestampedImage(Protocol):
    """What ``synchronise`` needs from a frame (``tactojax.hardware.Frame`` has it)."""

    image: UInt8[np.ndarray, "H W 3"]
    timestamp_s: float


@struct.dataclass
class SynchronisedTouch:
    """A tactile image with the gripper state at the time it was taken."""

    image: UInt8[np.ndarray, "H W 3"]
    """RGB tactile image on the sensor's grid."""
    timestamp_s: float
    """The frame's timestamp, seconds."""
    opening_mm: float
    """Distance between the undeformed gel surfaces, mm."""
    T_world_gripper: jaxlie.SE3
    """Gripper pose in the world frame, translation in mm."""


def opening_at(openings: OpeningSamples, timestamp_s: float, *, max_skew_s: float) -> float:
    """The gripper opening at ``timestamp_s``, mm.

    From samples: linear interpolation between the bracketing samples, the end sample outside
    their span; the nearest sample must lie within ``max_skew_s``. From a callable: its newest
    value, whose timestamp must lie within ``max_skew_s``. Raises ``StaleDataError`` otherwise.
    """
    if callable(openings):
        sample_time_s, opening_mm = openings()
        skew_s = abs(sample_time_s - timestamp_s)
        if skew_s > max_skew_s:
            raise StaleDataError("gripper opening", skew_s, max_skew_s,
                                 f"newest sample at {sample_time_s:.4f} s, frame at {timestamp_s:.4f} s")
        return float(opening_mm)
    samples = np.asarray(openings, dtype=np.float64).reshape(-1, 2)
    times, values = samples[:, 0], samples[:, 1]
    if len(times) == 0:
        raise StaleDataError("gripper opening", float("inf"), max_skew_s, "no samples")
    if np.any(np.diff(times) <= 0):
        raise ValueError("gripper opening timestamps must increase strictly")
    skew_s = float(np.min(np.abs(times - timestamp_s)))
    if skew_s > max_skew_s:
        raise StaleDataError("gripper opening", skew_s, max_skew_s, f"frame at {timestamp_s:.4f} s, samples span "
                             f"[{times[0]:.4f}, {times[-1]:.4f}] s")
    return float(np.interp(timestamp_s, times, values))


def synchronise(
    frame: TimestampedImage,
    openings: OpeningSamples,
    poses: PoseSource,
    *,
    max_skew_s: float,
    interpolate: bool = True,
) -> SynchronisedTouch:
    """Pair a frame with the gripper opening and the robot pose at its timestamp.

    Args:
        frame: the tactile frame (``image``, ``timestamp_s``).
        openings: gripper openings (see ``OpeningSamples``).
        poses: robot poses T_world_gripper (``PoseLog``, ``UdpPoseReceiver``, ...).
        max_skew_s: largest allowed time between the frame and each stream's nearest sample, s.
        interpolate: interpolate the pose between samples (else take the nearest).

    Returns:
        The ``SynchronisedTouch``; raises ``StaleDataError`` naming the stale stream.
    """
    opening_mm = opening_at(openings, frame.timestamp_s, max_skew_s=max_skew_s)
    pose = poses.pose_at(frame.timestamp_s, max_skew_s=max_skew_s, interpolate=interpolate)
    return SynchronisedTouch(image=frame.image, timestamp_s=frame.timestamp_s, opening_mm=opening_mm,
                             T_world_gripper=pose.T_world_gripper)
