"""Import a recorded ROS session (bag or MCAP) into the dataset format, as ``tactojax record`` would.

The touches are chosen and paired exactly as a live recording pairs them:

* ``touches="grasps"`` (default) replays :func:`~tactojax.hardware.record_grasps` on the
  recorded gripper openings: a grasp starts when the gripper, having closed by at least
  ``closing_mm`` from where it was open, holds still (its opening varies by at most
  ``still_mm`` over ``settle_s``); the touch is the first image taken ``settle_s`` after that,
  and the next grasp is armed once the gripper opens again by ``closing_mm``. A hold narrower
  than ``min_opening_mm`` closed on nothing and counts as missed. ``touches="every-frame"``
  makes every image message a touch (bags recorded with one image per touch).
* Each touch's image is paired with the gripper opening and ``T_world_gripper`` at its time by
  :func:`~tactojax.hardware.synchronise`: a stream with no sample within ``max_skew_s``
  (default 50 ms, ``tactojax record``'s) drops the touch as stale, and the run says why.
* The image is rectified onto the sensor's grid with the gel ``corners`` (as ``OpenCVCamera``
  does), and the touch is written by :class:`~tactojax.hardware.Recorder`: the same records and
  metadata as ``tactojax record`` (``tactojax map`` reads either unchanged).
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

import jaxlie
import numpy as np
from jaxtyping import Float, UInt8
from tqdm.auto import tqdm

from tactojax.hardware._camera import Frame, _resize, rectify_image
from tactojax.hardware._pose_source import StaleDataError
from tactojax.hardware._recorder import MAX_SKEW_S, Recorder
from tactojax.hardware._rosbag import (
    BagError, BagStreams, GripperJoints, Stamps, iter_images, open_bag, read_streams,
)
from tactojax.hardware._sync import synchronise
from tactojax.sensor import SensorSpec

SETTLE_S = 0.1
"""Time the gripper holds still before a grasp's touch is taken, s (``record_grasps``'s)."""


@dataclass(frozen=True)
class GraspDetection:
    """How grasps are found in a recorded gripper opening (module docstring)."""

    settle_s: float = SETTLE_S
    closing_mm: float = 1.0
    still_mm: float = 0.1
    min_opening_mm: float = 1.0


@dataclass
class BagImportSummary:
    """What an import did; ``as_dict`` is the CLI's ``--json``."""

    image_messages: int = 0
    """Messages on the image topic."""
    grasps: int = 0
    """Grasps detected in the openings (``touches="every-frame"``: image messages considered)."""
    recorded: int = 0
    """Touches written."""
    missed: int = 0
    """Grasps that closed on nothing (narrower than ``min_opening_mm``)."""
    stale: int = 0
    """Touches dropped because a stream had no sample within the maximum skew."""
    stale_reasons: list[str] = field(default_factory=list)
    """Why each stale touch was dropped."""
    span_s: dict[str, list[float]] = field(default_factory=dict)
    """First and last time of each stream (image, pose, gripper), seconds."""
    read_s: float = 0.0
    """Wall time of the whole import, seconds."""

    def as_dict(self) -> dict:
        return asdict(self)


def detect_grasps(
    openings: Float[np.ndarray, "M 2"], detection: GraspDetection = GraspDetection()
) -> list[tuple[float, float]]:
    """(time the hold starts, opening there in mm) for every grasp in recorded openings.

    Args:
        openings: (M, 2) rows of (timestamp_s, opening_mm), increasing times.
        detection: thresholds (see the module docstring).
    """
    times, widths = openings[:, 0], openings[:, 1]
    grasps, holding, open_level, hold_level = [], False, widths[0] if len(widths) else 0.0, 0.0
    for i in range(len(times)):
        if holding:
            if widths[i] >= hold_level + detection.closing_mm:
                holding, open_level = False, widths[i]
            continue
        open_level = max(open_level, widths[i])
        if open_level - widths[i] < detection.closing_mm:
            continue
        end = int(np.searchsorted(times, times[i] + detection.settle_s, side="left")) + 1
        if end > len(times):
            break  # the recording ends before the hold could be confirmed
        window = widths[i:end]
        if window.max() - window.min() <= detection.still_mm:
            holding, hold_level = True, widths[i]
            grasps.append((float(times[i]), float(widths[i])))
    return grasps


def to_sensor_image(rgb: UInt8[np.ndarray, "H W 3"], spec: SensorSpec,
                    corners: Sequence[Sequence[float]] | np.ndarray | None) -> UInt8[np.ndarray, "h w 3"]:
    """A raw camera image on the sensor's grid: rectified by the gel corners, else resized (as OpenCVCamera)."""
    if corners is not None:
        return rectify_image(rgb, corners, spec)
    return _resize(rgb, spec.shape)


def import_bag(
    bag: str | os.PathLike,
    out: str | os.PathLike,
    spec: SensorSpec,
    *,
    image_topic: str,
    gripper_topic: str,
    pose_topic: str | None = None,
    tf_frames: tuple[str, str] | None = None,
    object_id: str | None = None,
    corners: Sequence[Sequence[float]] | np.ndarray | None = None,
    joints: GripperJoints = GripperJoints(),
    T_child_gripper: jaxlie.SE3 | None = None,
    touches: Literal["grasps", "every-frame"] = "grasps",
    detection: GraspDetection = GraspDetection(),
    max_skew_s: float = MAX_SKEW_S,
    stamps: Stamps = "header",
    append: bool = False,
    progress: bool = True,
) -> BagImportSummary:
    """Import a ROS 1/2 bag or MCAP file into a dataset that ``tactojax map`` reads.

    Args:
        bag: a ``.bag`` file, a ROS 2 bag directory, or a ``.mcap`` / ``.db3`` file.
        out: dataset directory to create (or to append to with ``append``).
        spec: the tactile sensor: images are rectified to its grid, its metadata recorded.
        image_topic: ``sensor_msgs/Image`` or ``CompressedImage`` topic.
        gripper_topic: ``sensor_msgs/JointState`` topic of the gripper (see ``joints``).
        pose_topic: ``geometry_msgs/PoseStamped`` topic of ``T_world_gripper``; or
        tf_frames: (PARENT, CHILD): ``T_world_gripper`` is TF's ``T_PARENT_CHILD``.
        object_id: the object's name in the records (default: the bag's name).
        corners: (4, 2) gel corners in the raw image (TL, TR, BR, BL), or None.
        joints: which joints give the opening and how (:class:`GripperJoints`).
        T_child_gripper: tactojax's gripper frame in the recorded frame, mm.
        touches: ``"grasps"`` (one touch per detected grasp) or ``"every-frame"``.
        detection: grasp thresholds.
        max_skew_s: largest time between an image and its opening and pose, s.
        stamps: ``"header"`` stamps or the bag's ``"receive"`` times.
        append: add to an existing dataset instead of refusing it.
        progress: show progress bars.

    Returns:
        The :class:`BagImportSummary`. Raises ``BagError`` (a ``ValueError``) naming the file or
        topic for an unreadable bag, a missing topic, an unsupported encoding, streams that never
        overlap, or when no touch at all can be synchronised.
    """
    if touches not in ("grasps", "every-frame"):
        raise ValueError(f"touches must be 'grasps' or 'every-frame', got {touches!r}")
    start = time.perf_counter()
    bag, out = Path(bag), Path(out)
    if (out / "manifest.json").exists() and not append:
        raise ValueError(f"{out} already holds a dataset; choose a new directory or append to it")
    summary = BagImportSummary()
    with open_bag(bag) as reader:
        topics = reader.topics
        relevant = [image_topic, gripper_topic, *([pose_topic] if pose_topic else ["/tf", "/tf_static"])]
        total = sum(topics[t].msgcount for t in relevant if t in topics)
        with tqdm(total=total, desc=f"read {bag.name}", unit="msg", disable=not progress) as bar:
            streams = read_streams(reader, image_topic=image_topic, gripper_topic=gripper_topic,
                                   pose_topic=pose_topic, tf_frames=tf_frames, joints=joints,
                                   T_child_gripper=T_child_gripper, stamps=stamps, progress=bar.update)
        summary.image_messages = len(streams.image_times_s)
        summary.span_s = _check_overlap(streams, image_topic, gripper_topic, pose_topic or
                                        f"TF {tf_frames[0]} -> {tf_frames[1]}", max_skew_s)
        candidates = _touch_candidates(streams, touches, detection, summary)
        placeholder = np.zeros((0, 0, 3), np.uint8)
        paired = {}
        for index in candidates:
            frame = Frame(image=placeholder, timestamp_s=float(streams.image_times_s[index]), index=index)
            try:
                paired[index] = synchronise(frame, streams.openings, streams.poses, max_skew_s=max_skew_s)
            except StaleDataError as error:
                summary.stale += 1
                summary.stale_reasons.append(_name_stream(str(error), gripper_topic))
        if not paired:
            reason = summary.stale_reasons[0] if summary.stale_reasons else "no grasp was detected in the openings"
            raise BagError(f"{bag}: no touch could be taken from {image_topic!r} ({len(candidates)} candidate "
                           f"frames): {reason}")
        source = {"bag": str(bag), "image_topic": image_topic, "gripper_topic": gripper_topic,
                  "pose": pose_topic or {"tf": list(tf_frames)}, "corners": None if corners is None
                  else np.asarray(corners, float).tolist(), "joints": list(joints.names), "joint_scale": joints.scale,
                  "opening_offset_mm": joints.offset_mm, "stamps": stamps, "touches": touches}
        with Recorder(out, spec, source=source) as recorder, \
                tqdm(total=summary.image_messages, desc="import touches", unit="image", disable=not progress) as bar:
            for index, raw in iter_images(reader, image_topic, sorted(paired), progress=bar.update):
                try:
                    image = to_sensor_image(raw, spec, corners)
                except ValueError as error:
                    raise BagError(f"image topic {image_topic!r}: {error}") from None
                recorder.write(paired[index].replace(image=image), object_id=object_id or bag.stem)
                summary.recorded += 1
    for reason in summary.stale_reasons[:5]:
        tqdm.write(f"touch skipped: {reason}")
    summary.read_s = time.perf_counter() - start
    return summary


def _touch_candidates(streams: BagStreams, touches: str, detection: GraspDetection,
                      summary: BagImportSummary) -> list[int]:
    """Indices (bag order) of the image messages that become touches."""
    if touches == "every-frame":
        summary.grasps = len(streams.image_times_s)
        return list(range(len(streams.image_times_s)))
    order = np.argsort(streams.image_times_s, kind="stable")
    sorted_times = streams.image_times_s[order]
    chosen = []
    for start_s, opening_mm in detect_grasps(streams.openings, detection):
        summary.grasps += 1
        if opening_mm < detection.min_opening_mm:
            summary.missed += 1
            continue
        after = int(np.searchsorted(sorted_times, start_s + detection.settle_s, side="left"))
        if after == len(sorted_times):
            summary.stale += 1
            summary.stale_reasons.append(f"no image after the grasp at {start_s:.3f} s")
            continue
        chosen.append(int(order[after]))
    return chosen


def _check_overlap(streams: BagStreams, image_topic: str, gripper_topic: str, pose_name: str,
                   max_skew_s: float) -> dict[str, list[float]]:
    """Each stream's span; BagError naming the topics when the poses or openings never meet the images."""
    images = (float(streams.image_times_s.min()), float(streams.image_times_s.max()))
    spans = {"image": images, "gripper": (float(streams.openings[0, 0]), float(streams.openings[-1, 0])),
             "pose": streams.pose_span_s}
    names = {"gripper": f"gripper topic {gripper_topic!r}", "pose": (pose_name if pose_name.startswith("TF")
                                                                   else f"pose topic {pose_name!r}")}
    for stream, (first, last) in spans.items():
        if stream != "image" and (last < images[0] - max_skew_s or first > images[1] + max_skew_s):
            raise BagError(f"{names[stream]} spans [{first:.3f}, {last:.3f}] s, which never overlaps the image topic "
                           f"{image_topic!r} at [{images[0]:.3f}, {images[1]:.3f}] s (max skew "
                           f"{max_skew_s * 1e3:.0f} ms): different clocks? try stamps 'receive' (--stamps receive)")
    return {stream: [float(t) if np.isfinite(t) else None for t in span] for stream, span in spans.items()}


def _name_stream(message: str, gripper_topic: str) -> str:
    return message.replace("gripper opening is stale", f"gripper topic {gripper_topic!r} is stale")
