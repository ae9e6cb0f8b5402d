"""Read a recorded robot session from a ROS bag: tactile images, gripper poses, gripper openings.

Reads ROS 1 bags (``.bag``), ROS 2 bags (a directory with ``metadata.yaml``, sqlite3 or MCAP
storage) and single ROS 2 storage files (``.mcap``, ``.db3``) with the pure-Python ``rosbags``
package (no ROS install; optional extra ``ros``). Every error names the bag, the topic or the
TF frames it is about.

Messages and conventions:

* Images: ``sensor_msgs/Image`` with encoding ``rgb8``, ``bgr8``, ``rgba8``, ``bgra8`` or
  ``mono8``, or ``sensor_msgs/CompressedImage`` (JPEG, PNG: anything OpenCV decodes to 8 bits).
  Other encodings (16-bit, Bayer, YUV, ...) are refused naming the topic and the encoding.
* Gripper pose ``T_world_gripper``: ``geometry_msgs/PoseStamped`` (or ``TransformStamped``) on
  a topic, or the TF tree (``tf2_msgs/TFMessage`` on ``/tf`` and ``/tf_static``) chained from a
  PARENT frame (the world) to a CHILD frame (the gripper): each edge is looked up at the
  frame's time as a pose stream is (nearest sample within the skew, SLERP between samples),
  static edges at any time. ROS translations are metres; they become millimetres here.
  ``T_child_gripper`` (mm) places tactojax's gripper frame (midway between the gel planes, z
  the approach, y the closing axis towards the sensor finger) in the recorded frame.
* Gripper opening: ``sensor_msgs/JointState``. The opening is ``scale * sum(|position|)`` over
  the named joints (default: every joint of the message) plus ``offset_mm``; ``scale`` defaults
  to 1000 (prismatic joints in metres). A Franka Hand's two finger joints (each finger's
  distance from the centre) sum to its width; a gripper that publishes the width as one joint
  is that joint. tactojax's opening is the distance between the undeformed gel surfaces, so
  ``offset_mm`` subtracts the gels' and fingertips' thickness from the jaw width.
* Time: the messages' ``header.stamp`` (the time the data was taken), or with
  ``stamps="receive"`` the bag's receive times (for drivers that leave stamps at zero).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import jaxlie
import numpy as np
from jaxtyping import Float, UInt8

from tactojax.hardware._pose_source import PoseLog, PoseSample, pose_at_time

Stamps = Literal["header", "receive"]
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TransformStamped")
TF_TYPE = "tf2_msgs/msg/TFMessage"
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
TF_TOPICS = ("/tf", "/tf_static")
RAW_ENCODINGS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}
"""Supported ``sensor_msgs/Image`` encodings and their channel counts (8 bits each)."""
M_TO_MM = 1000.0


class BagError(ValueError):
    """A bag cannot be read, or lacks or holds unusable data on a topic; the message names it."""


@dataclass(frozen=True)
class GripperJoints:
    """How a ``sensor_msgs/JointState`` gives the gripper opening (module docstring)."""

    names: tuple[str, ...] = ()
    """Joints summed (absolute positions); empty: every joint of the message."""
    scale: float = M_TO_MM
    """Joint position units to mm (1000 for metres)."""
    offset_mm: float = 0.0
    """Added to the scaled sum: the opening between the gel surfaces minus the jaw width, mm."""


@dataclass
class BagStreams:
    """The small streams of a bag, read in one pass, and the times of its image messages."""

    image_times_s: Float[np.ndarray, " N"]
    """Time of each image message on the image topic (bag order), seconds."""
    poses: PoseTopic | TransformChain
    """``T_world_gripper`` over time (mm), a :class:`~tactojax.hardware.PoseSource`."""
    openings: Float[np.ndarray, "M 2"]
    """(timestamp_s, opening_mm) rows, increasing times."""
    pose_span_s: tuple[float, float]
    """Times over which poses are known (the dynamic TF edges' common span), seconds."""


@contextlib.contextmanager
def open_bag(path: str | os.PathLike) -> Iterator:
    """Open a ROS 1 bag, ROS 2 bag directory, ``.mcap`` or ``.db3`` as a ``rosbags`` ``AnyReader``.

    Raises :class:`BagError` naming the file when it is missing, not a bag, truncated or corrupt.
    """
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise ImportError("reading ROS bags needs the rosbags package: pip install 'tactojax[ros]'") from None
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no bag at {path}")
    reader = AnyReader([path])
    try:
        reader.open()
    except Exception as error:  # rosbags, sqlite3 and yaml raise many types for a damaged file
        raise BagError(f"{path} cannot be read as a ROS bag (truncated or corrupt?): {error}") from None
    try:
        yield reader
    finally:
        reader.close()


def bag_topics(path: str | os.PathLike) -> dict[str, tuple[str, int]]:
    """``{topic: (message type, message count)}`` of a bag."""
    with open_bag(path) as reader:
        return {name: (info.msgtype or "mixed types", info.msgcount) for name, info in reader.topics.items()}


def topic_connections(reader, topic: str, types: Sequence[str], role: str) -> list:
    """The bag's connections on ``topic``; BagError naming it when absent or of another type."""
    connections = [c for c in reader.connections if c.topic == topic]
    if not connections:
        listing = ", ".join(f"{c.topic} ({c.msgtype})" for c in sorted(reader.connections, key=lambda c: c.topic))
        raise BagError(f"{_bag_name(reader)} has no {role} topic {topic!r}; its topics: {listing or 'none'}")
    wrong = sorted({c.msgtype for c in connections} - set(types))
    if wrong:
        raise BagError(f"{role} topic {topic!r} holds {', '.join(wrong)}; expected {' or '.join(types)}")
    return connections


def read_streams(
    reader,
    *,
    image_topic: str,
    gripper_topic: str,
    pose_topic: str | None = None,
    tf_frames: tuple[str, str] | None = None,
    joints: GripperJoints = GripperJoints(),
    T_child_gripper: jaxlie.SE3 | None = None,
    stamps: Stamps = "header",
    progress=None,
) -> BagStreams:
    """Read poses, openings and image times in one pass over the bag (images are not decoded).

    Args:
        reader: an open bag (:func:`open_bag`).
        image_topic: ``sensor_msgs/Image`` or ``CompressedImage`` topic.
        gripper_topic: ``sensor_msgs/JointState`` topic.
        pose_topic: ``geometry_msgs/PoseStamped`` topic of ``T_world_gripper``; or
        tf_frames: (PARENT, CHILD) frames chained through ``/tf`` and ``/tf_static``.
        joints: which joints give the opening.
        T_child_gripper: tactojax's gripper frame in the recorded frame, mm (default identity).
        stamps: ``"header"`` or ``"receive"`` times.
        progress: a callable advanced by one per message read (e.g. ``tqdm.update``).
    """
    if (pose_topic is None) == (tf_frames is None):
        raise ValueError("give either a pose topic or TF frames (PARENT, CHILD), not both")
    if stamps not in ("header", "receive"):
        raise ValueError(f"stamps must be 'header' or 'receive', got {stamps!r}")
    image_connections = topic_connections(reader, image_topic, IMAGE_TYPES, "image")
    joint_connections = topic_connections(reader, gripper_topic, (JOINT_STATE_TYPE,), "gripper")
    if pose_topic is not None:
        pose_connections = topic_connections(reader, pose_topic, POSE_TYPES, "pose")
    else:
        pose_connections = [c for c in reader.connections if c.topic in TF_TOPICS]
        if not pose_connections:
            raise BagError(f"{_bag_name(reader)} has no /tf or /tf_static topic to chain "
                           f"{tf_frames[0]} -> {tf_frames[1]}")
        pose_connections = [c for c in pose_connections if _check_type(c, (TF_TYPE,), "TF")]
    image_times, joint_samples, pose_samples = [], [], []
    edges: dict[tuple[str, str], list] = {}
    static: dict[tuple[str, str], np.ndarray] = {}
    for connection, receive_ns, raw in reader.messages(connections=image_connections + joint_connections
                                                       + pose_connections):
        message = _deserialize(reader, raw, connection)
        topic = connection.topic
        if topic == image_topic:
            image_times.append(_time_s(message, receive_ns, stamps, topic))
        elif topic == gripper_topic:
            joint_samples.append((_time_s(message, receive_ns, stamps, topic), _opening_mm(message, joints, topic)))
        elif pose_topic is not None:
            pose_samples.append((_time_s(message, receive_ns, stamps, topic), _pose_wxyz_xyz_mm(message)))
        else:
            for transform in message.transforms:
                edge = (_frame(transform.header.frame_id), _frame(transform.child_frame_id))
                pose = _transform_wxyz_xyz_mm(transform.transform)
                if topic == "/tf_static":
                    if not np.all(np.isfinite(pose)):
                        raise BagError(f"/tf_static: the transform {edge[0]} -> {edge[1]} is not a valid pose")
                    static[edge] = pose
                else:
                    edges.setdefault(edge, []).append((_time_s(transform, receive_ns, stamps, topic), pose))
        if progress is not None:
            progress(1)
    if not image_times:
        raise BagError(f"image topic {image_topic!r} has no messages")
    openings = _sorted_samples(joint_samples, gripper_topic)
    openings = np.column_stack([openings[0], openings[1][:, 0]]) if len(openings[0]) else np.zeros((0, 2))
    if len(openings) == 0:
        raise BagError(f"gripper topic {gripper_topic!r} has no messages")
    if pose_topic is not None:
        times, poses = _sorted_samples(pose_samples, pose_topic)
        if len(times) == 0:
            raise BagError(f"pose topic {pose_topic!r} has no messages")
        try:
            pose_log = PoseTopic(pose_topic, times, _then(poses, T_child_gripper))
        except ValueError as error:
            raise BagError(f"pose topic {pose_topic!r}: {error}") from None
        return BagStreams(np.asarray(image_times), pose_log, openings, (float(times[0]), float(times[-1])))
    chain = TransformChain.from_edges(*tf_frames, edges, static, T_child_gripper=T_child_gripper)
    return BagStreams(np.asarray(image_times), chain, openings, chain.span_s)


def iter_images(
    reader, image_topic: str, wanted: Sequence[int] | None = None, *, progress=None
) -> Iterator[tuple[int, UInt8[np.ndarray, "H W 3"]]]:
    """Decode the image topic's messages ``wanted`` (indices in bag order; None: all) as RGB uint8.

    Yields (index, image) in bag order; ``progress`` is advanced once per message passed.
    """
    connections = topic_connections(reader, image_topic, IMAGE_TYPES, "image")
    wanted_set = None if wanted is None else set(int(i) for i in wanted)
    for index, (connection, _, raw) in enumerate(reader.messages(connections=connections)):
        if progress is not None:
            progress(1)
        if wanted_set is not None and index not in wanted_set:
            continue
        yield index, decode_image(_deserialize(reader, raw, connection), image_topic)


def decode_image(message, topic: str) -> UInt8[np.ndarray, "H W 3"]:
    """A ``sensor_msgs/Image`` or ``CompressedImage`` as RGB uint8; BagError naming the topic."""
    data = np.asarray(message.data, dtype=np.uint8)
    if hasattr(message, "format"):  # CompressedImage
        decoded = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if decoded is None:
            raise BagError(f"image topic {topic!r}: cannot decode a CompressedImage of format {message.format!r}")
        if decoded.dtype != np.uint8:
            raise BagError(f"image topic {topic!r}: compressed images of {decoded.dtype} are not supported "
                           f"(format {message.format!r}); tactile images must be 8-bit")
        if decoded.ndim == 2:
            return cv2.cvtColor(decoded, cv2.COLOR_GRAY2RGB)
        return cv2.cvtColor(decoded, cv2.COLOR_BGRA2RGB if decoded.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    encoding = message.encoding.lower()
    if encoding not in RAW_ENCODINGS:
        raise BagError(f"image topic {topic!r}: unsupported encoding {message.encoding!r}; supported: "
                       f"{', '.join(RAW_ENCODINGS)} and sensor_msgs/CompressedImage")
    channels, height, width, step = RAW_ENCODINGS[encoding], message.height, message.width, message.step
    if step < width * channels or len(data) < step * height:
        raise BagError(f"image topic {topic!r}: a {width} x {height} {encoding} image needs {width * channels} "
                       f"bytes a row and {step * height} in all, got step {step} and {len(data)} bytes")
    pixels = data[:step * height].reshape(height, step)[:, :width * channels].reshape(height, width, channels)
    conversion = {"rgb8": None, "bgr8": cv2.COLOR_BGR2RGB, "rgba8": cv2.COLOR_RGBA2RGB,
                  "bgra8": cv2.COLOR_BGRA2RGB, "mono8": cv2.COLOR_GRAY2RGB}[encoding]
    image = pixels if conversion is None else cv2.cvtColor(np.ascontiguousarray(pixels), conversion)
    return np.ascontiguousarray(image)


class PoseTopic(PoseLog):
    """The poses of one topic (a :class:`PoseLog` whose stale lookups name the topic)."""

    def __init__(self, topic: str, timestamps_s: Float[np.ndarray, " N"], wxyz_xyz: Float[np.ndarray, "N 7"]):
        super().__init__(timestamps_s, wxyz_xyz)
        self.topic = topic

    def pose_at(self, timestamp_s: float, *, max_skew_s: float, interpolate: bool = True) -> PoseSample:
        return pose_at_time(self.timestamps_s, self.wxyz_xyz, timestamp_s, max_skew_s=max_skew_s,
                            interpolate=interpolate, stream=f"pose topic {self.topic!r}")


class TransformChain:
    """``T_parent_child`` over time, chained through TF edges (a :class:`PoseSource`).

    Args:
        parent, child: frame names (leading ``/`` ignored).
        path: the edges from ``parent`` to ``child``: (name, static pose or None, times, poses,
            inverted) with poses (N, 7) wxyz + xyz mm of ``T_edgeparent_edgechild``.
        T_child_gripper: appended to the chain, mm.
    """

    def __init__(self, parent: str, child: str, path: list, *, T_child_gripper: jaxlie.SE3 | None = None):
        self.parent, self.child, self._path = parent, child, path
        self._T_child_gripper = None if T_child_gripper is None else np.asarray(T_child_gripper.wxyz_xyz, np.float64)
        dynamic = [times for _, pose, times, _, _ in path if pose is None]
        self.span_s = ((max(float(t[0]) for t in dynamic), min(float(t[-1]) for t in dynamic)) if dynamic
                       else (-np.inf, np.inf))
        """Times every dynamic edge has samples around, seconds (infinite when all are static)."""

    @classmethod
    def from_edges(cls, parent: str, child: str, edges: dict, static: dict, *,
                   T_child_gripper: jaxlie.SE3 | None = None) -> TransformChain:
        """Find the path between two frames in the TF tree made of dynamic and static edges."""
        parent, child = _frame(parent), _frame(child)
        parents = {edge_child: edge_parent for edge_parent, edge_child in [*edges, *static]}
        up_from_child, up_from_parent = _ancestors(child, parents), _ancestors(parent, parents)
        common = next((frame for frame in up_from_child if frame in up_from_parent), None)
        if common is None:
            known = sorted({f for edge in [*edges, *static] for f in edge})
            raise BagError(f"TF has no chain from {parent!r} to {child!r}; frames in /tf and /tf_static: "
                           f"{', '.join(known) or 'none'}")
        path = []
        descending = up_from_parent[:up_from_parent.index(common)]  # parent ... up to common (excluded)
        for frame in descending:  # parent -> its parent: inverted edges
            path.append(_edge(parents[frame], frame, edges, static, inverted=True))
        ascending = up_from_child[:up_from_child.index(common)]
        for frame in reversed(ascending):  # common -> ... -> child
            path.append(_edge(parents[frame], frame, edges, static, inverted=False))
        return cls(parent, child, path, T_child_gripper=T_child_gripper)

    def pose_at(self, timestamp_s: float, *, max_skew_s: float, interpolate: bool = True) -> PoseSample:
        """``T_parent_child`` (then ``T_child_gripper``) at a time; StaleDataError names the stale edge."""
        total = jaxlie.SE3.identity()
        for name, pose, times, poses, inverted in self._path:
            if pose is None:
                pose = np.asarray(pose_at_time(times, poses, timestamp_s, max_skew_s=max_skew_s,
                                               interpolate=interpolate, stream=name).T_world_gripper.wxyz_xyz)
            T = jaxlie.SE3(np.asarray(pose, np.float64))
            total = total @ (T.inverse() if inverted else T)
        if self._T_child_gripper is not None:
            total = total @ jaxlie.SE3(self._T_child_gripper)
        return PoseSample(timestamp_s=float(timestamp_s), T_world_gripper=jaxlie.SE3(np.asarray(total.wxyz_xyz,
                                                                                               np.float64)))


def _ancestors(frame: str, parents: dict[str, str]) -> list[str]:
    """``frame`` and its ancestors up to the root."""
    chain = [frame]
    while chain[-1] in parents and parents[chain[-1]] not in chain:
        chain.append(parents[chain[-1]])
    return chain


def _edge(parent: str, child: str, edges: dict, static: dict, *, inverted: bool) -> tuple:
    name = f"TF {parent} -> {child}"
    if (parent, child) in static and (parent, child) not in edges:
        return name, static[(parent, child)], None, None, inverted
    times, poses = _sorted_samples(edges[(parent, child)], name)
    return name, None, times, poses, inverted


def _check_type(connection, types: Sequence[str], role: str) -> bool:
    if connection.msgtype not in types:
        raise BagError(f"{role} topic {connection.topic!r} holds {connection.msgtype}; expected {' or '.join(types)}")
    return True


def _deserialize(reader, raw: bytes, connection):
    try:
        return reader.deserialize(raw, connection.msgtype)
    except Exception as error:
        raise BagError(f"topic {connection.topic!r}: a {connection.msgtype} message cannot be decoded "
                       f"(corrupt bag?): {error}") from None


def _bag_name(reader) -> str:
    return ", ".join(str(path) for path in reader.paths)


def _frame(name: str) -> str:
    return name.lstrip("/")


def _time_s(message, receive_ns: int, stamps: Stamps, topic: str) -> float:
    if stamps == "receive":
        return receive_ns * 1e-9
    stamp = message.header.stamp
    if stamp.sec == 0 and stamp.nanosec == 0:
        raise BagError(f"topic {topic!r}: a message has no header stamp (zero); use the bag's receive "
                       "times instead (stamps='receive', --stamps receive)")
    return stamp.sec + stamp.nanosec * 1e-9


def _pose_wxyz_xyz_mm(message) -> np.ndarray:
    if hasattr(message, "pose"):
        p, q = message.pose.position, message.pose.orientation
        return np.array([q.w, q.x, q.y, q.z, p.x * M_TO_MM, p.y * M_TO_MM, p.z * M_TO_MM])
    return _transform_wxyz_xyz_mm(message.transform)


def _transform_wxyz_xyz_mm(transform) -> np.ndarray:
    """A TF transform as wxyz + xyz mm, the quaternion normalised (TF publishers rarely send exact units)."""
    t, q = transform.translation, transform.rotation
    wxyz = np.array([q.w, q.x, q.y, q.z])
    norm = np.linalg.norm(wxyz)
    wxyz = wxyz / norm if norm > 0.5 else np.full(4, np.nan)  # NaN: refused by _sorted_samples
    return np.concatenate([wxyz, [t.x * M_TO_MM, t.y * M_TO_MM, t.z * M_TO_MM]])


def _opening_mm(message, joints: GripperJoints, topic: str) -> float:
    names, positions = list(message.name), np.asarray(message.position, np.float64)
    if len(positions) != len(names):
        raise BagError(f"gripper topic {topic!r}: a JointState has {len(names)} names but "
                       f"{len(positions)} positions")
    if joints.names:
        missing = [name for name in joints.names if name not in names]
        if missing:
            raise BagError(f"gripper topic {topic!r}: no joint {', '.join(map(repr, missing))} in a JointState "
                           f"(its joints: {', '.join(names) or 'none'})")
        positions = positions[[names.index(name) for name in joints.names]]
    elif len(positions) == 0:
        raise BagError(f"gripper topic {topic!r}: a JointState has no joint positions")
    return float(joints.scale * np.abs(positions).sum() + joints.offset_mm)


def _sorted_samples(samples: list, stream: str) -> tuple[np.ndarray, np.ndarray]:
    """(times, values) in time order; samples sharing a time keep the last one."""
    if not samples:
        return np.zeros(0), np.zeros((0, 1))
    times = np.array([t for t, _ in samples], np.float64)
    values = np.array([np.atleast_1d(v) for _, v in samples], np.float64)
    order = np.argsort(times, kind="stable")
    times, values = times[order], values[order]
    keep = np.append(np.diff(times) > 0, True)
    if not np.all(np.isfinite(values)):
        raise BagError(f"{stream}: holds non-finite values")
    return times[keep], values[keep]


def _then(wxyz_xyz: np.ndarray, T_child_gripper: jaxlie.SE3 | None) -> np.ndarray:
    if T_child_gripper is None:
        return wxyz_xyz
    norms = np.linalg.norm(wxyz_xyz[:, :4], axis=1, keepdims=True)
    poses = np.concatenate([wxyz_xyz[:, :4] / norms, wxyz_xyz[:, 4:]], axis=1)
    return np.asarray((jaxlie.SE3(poses) @ T_child_gripper).wxyz_xyz, np.float64)
