"""Robot poses ``T_world_gripper`` over time, from a log file or a UDP stream, looked up at a time.

Poses are ``jaxlie.SE3`` (quaternion wxyz, translation in mm) mapping gripper-frame points to
the world frame. Lookups run in numpy (no jax compilation per sample or packet); the returned
``PoseSample`` wraps float64 numpy arrays in a ``jaxlie.SE3``.

File formats (``read_pose_log`` / ``write_pose_log``, chosen by suffix):

* CSV (``.csv``): the header ``timestamp_s,qw,qx,qy,qz,x_mm,y_mm,z_mm``, then one sample a line.
* JSON (``.json``): a list of ``{"timestamp_s": t, "T_world_gripper": [qw, qx, qy, qz, x_mm,
  y_mm, z_mm]}`` objects.

Timestamps must increase strictly. Quaternions within ``QUATERNION_NORM_TOLERANCE`` of unit
norm are normalised; others are rejected. Errors name the CSV line or JSON entry.

UDP packet (``encode_pose_packet``): 68 bytes, little-endian: the 4 ASCII bytes ``TJP1``, then
8 float64: timestamp_s, qw, qx, qy, qz, x_mm, y_mm, z_mm (struct format ``<4s8d``).

Lookup at a time t (``pose_at``): the nearest sample must lie within ``max_skew_s`` of t, else
``StaleDataError``. Between two samples the pose is interpolated (quaternion SLERP along the
shorter arc, translation linearly); before the first or after the last sample the end sample is
returned (no extrapolation). ``interpolate=False`` returns the nearest sample.
"""

from __future__ import annotations

import csv
import json
import os
import socket
import struct
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Literal, Protocol, Self

import jaxlie
import numpy as np
from jaxtyping import Float

from tactojax import _struct as pytree_struct

CSV_HEADER = ("timestamp_s", "qw", "qx", "qy", "qz", "x_mm", "y_mm", "z_mm")
QUATERNION_NORM_TOLERANCE = 1e-3
PACKET_MAGIC = b"TJP1"
PACKET_FORMAT = "<4s8d"
PACKET_SIZE = struct.calcsize(PACKET_FORMAT)


class StaleDataError(RuntimeError):
    """No sample of a stream lies close enough in time to the one requested."""

    def __init__(self, stream: str, skew_s: float, max_skew_s: float, detail: str = ""):
        self.stream = stream
        """Which stream was stale, e.g. "robot pose" or "gripper opening"."""
        self.skew_s = skew_s
        """Time from the request to the nearest sample, seconds (inf when there is none)."""
        self.max_skew_s = max_skew_s
        super().__init__(f"{stream} is stale: nearest sample is {skew_s:.4f} s away "
                         f"(max {max_skew_s:.4f} s){': ' + detail if detail else ''}")


@pytree_struct.dataclass
class PoseSample:
    """The gripper's pose at one time."""

    timestamp_s: float
    """Time the pose holds at, seconds, on the source's clock."""
    T_world_gripper: jaxlie.SE3
    """Gripper pose in the world frame, translation in mm (float64 numpy leaves)."""


class PoseSource(Protocol):
    """Anything that gives the gripper pose at a time (``PoseLog``, ``UdpPoseReceiver``)."""

    def pose_at(self, timestamp_s: float, *, max_skew_s: float, interpolate: bool = True) -> PoseSample: ...


class PoseLog:
    """A recorded trajectory of gripper poses, validated and ready for lookups.

    Args:
        timestamps_s: (N,) strictly increasing times, seconds.
        wxyz_xyz: (N, 7) poses T_world_gripper: unit quaternion wxyz, then translation in mm.
    """

    def __init__(self, timestamps_s: Float[np.ndarray, " N"], wxyz_xyz: Float[np.ndarray, "N 7"]):
        self.timestamps_s, self.wxyz_xyz = _validated_samples(timestamps_s, wxyz_xyz, lambda i: f"sample {i}")

    def __len__(self) -> int:
        return len(self.timestamps_s)

    def pose_at(self, timestamp_s: float, *, max_skew_s: float, interpolate: bool = True) -> PoseSample:
        """The pose at ``timestamp_s`` (see the module docstring); raises ``StaleDataError``."""
        return pose_at_time(self.timestamps_s, self.wxyz_xyz, timestamp_s, max_skew_s=max_skew_s,
                            interpolate=interpolate)


def read_pose_log(path: str | os.PathLike) -> PoseLog:
    """Read a CSV or JSON pose log (formats in the module docstring)."""
    path = Path(path)
    if path.suffix.lower() == ".csv":
        return _read_csv(path)
    if path.suffix.lower() == ".json":
        return _read_json(path)
    raise ValueError(f"pose log must be .csv or .json, got {path.name!r}")


def write_pose_log(path: str | os.PathLike, log: PoseLog) -> Path:
    """Write a pose log as CSV or JSON by suffix; floats are written exactly (round-trip repr)."""
    path = Path(path)
    rows = [(float(t), [float(v) for v in pose]) for t, pose in zip(log.timestamps_s, log.wxyz_xyz, strict=True)]
    if path.suffix.lower() == ".csv":
        lines = [",".join(CSV_HEADER)] + [",".join(repr(v) for v in [t, *pose]) for t, pose in rows]
        path.write_text("\n".join(lines) + "\n")
    elif path.suffix.lower() == ".json":
        path.write_text(json.dumps([{"timestamp_s": t, "T_world_gripper": pose} for t, pose in rows], indent=1))
    else:
        raise ValueError(f"pose log must be .csv or .json, got {path.name!r}")
    return path


def pose_at_time(
    timestamps_s: Float[np.ndarray, " N"],
    wxyz_xyz: Float[np.ndarray, "N 7"],
    timestamp_s: float,
    *,
    max_skew_s: float,
    interpolate: bool = True,
    stream: str = "robot pose",
) -> PoseSample:
    """Look up a pose in sorted samples: nearest within ``max_skew_s``, SLERP between neighbours.

    Args:
        timestamps_s: (N,) strictly increasing, seconds.
        wxyz_xyz: (N, 7) unit quaternions wxyz and translations, mm.
        timestamp_s: time of the request, seconds.
        max_skew_s: largest allowed time to the nearest sample, seconds.
        interpolate: interpolate between the bracketing samples, else return the nearest.
        stream: name used in the ``StaleDataError``.
    """
    if len(timestamps_s) == 0:
        raise StaleDataError(stream, float("inf"), max_skew_s, "no samples yet")
    after = int(np.searchsorted(timestamps_s, timestamp_s))
    neighbours = [i for i in (after - 1, after) if 0 <= i < len(timestamps_s)]
    nearest = min(neighbours, key=lambda i: abs(timestamps_s[i] - timestamp_s))
    skew_s = abs(float(timestamps_s[nearest]) - timestamp_s)
    if skew_s > max_skew_s:
        raise StaleDataError(stream, skew_s, max_skew_s, f"requested t = {timestamp_s:.4f} s, samples span "
                             f"[{timestamps_s[0]:.4f}, {timestamps_s[-1]:.4f}] s")
    if not interpolate or len(neighbours) < 2 or skew_s == 0.0:
        return PoseSample(timestamp_s=float(timestamps_s[nearest]),
                          T_world_gripper=jaxlie.SE3(wxyz_xyz=wxyz_xyz[nearest].copy()))
    t0, t1 = timestamps_s[after - 1], timestamps_s[after]
    fraction = (timestamp_s - t0) / (t1 - t0)
    start, end = wxyz_xyz[after - 1], wxyz_xyz[after]
    pose = np.concatenate([_slerp(start[:4], end[:4], fraction), start[4:] + fraction * (end[4:] - start[4:])])
    return PoseSample(timestamp_s=float(timestamp_s), T_world_gripper=jaxlie.SE3(wxyz_xyz=pose))


def _slerp(q0: np.ndarray, q1: np.ndarray, fraction: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions along the shorter arc."""
    cosine = float(q0 @ q1)
    if cosine < 0.0:
        q1, cosine = -q1, -cosine
    if cosine > 1.0 - 1e-12:
        q = q0 + fraction * (q1 - q0)
        return q / np.linalg.norm(q)
    angle = np.arccos(cosine)
    return (np.sin((1.0 - fraction) * angle) * q0 + np.sin(fraction * angle) * q1) / np.sin(angle)


def _validated_samples(timestamps_s, wxyz_xyz, row_name: Callable[[int], str]) -> tuple[np.ndarray, np.ndarray]:
    """(N,) and (N, 7) float64 arrays, quaternions normalised; ValueError naming the first bad row."""
    times = np.array(timestamps_s, dtype=np.float64)
    poses = np.array(wxyz_xyz, dtype=np.float64)
    if times.ndim != 1 or poses.shape != (len(times), 7):
        raise ValueError(f"expected (N,) timestamps and (N, 7) poses, got {times.shape} and {poses.shape}")
    if len(times) == 0:
        raise ValueError("a pose log needs at least one sample")
    not_finite = np.flatnonzero(~(np.isfinite(times) & np.all(np.isfinite(poses), axis=1)))
    if len(not_finite):
        i = not_finite[0]
        raise ValueError(f"{row_name(i)}: values must be finite, got {float(times[i])!r}, {poses[i].tolist()}")
    not_increasing = np.flatnonzero(np.diff(times) <= 0) + 1
    if len(not_increasing):
        i = not_increasing[0]
        raise ValueError(f"{row_name(i)}: timestamp {float(times[i])!r} s is not after the previous "
                         f"{float(times[i - 1])!r} s")
    norms = np.linalg.norm(poses[:, :4], axis=1)
    not_unit = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
    if len(not_unit):
        i = not_unit[0]
        raise ValueError(f"{row_name(i)}: quaternion norm {norms[i]:.6f} is not within "
                         f"{QUATERNION_NORM_TOLERANCE} of 1")
    poses[:, :4] /= norms[:, None]
    return times, poses


def _read_csv(path: Path) -> PoseLog:
    with path.open(newline="") as file:
        rows = list(csv.reader(file))
    if not rows or tuple(field.strip() for field in rows[0]) != CSV_HEADER:
        raise ValueError(f"{path.name} line 1: header must be {','.join(CSV_HEADER)!r}, "
                         f"got {','.join(rows[0]) if rows else 'an empty file'!r}")
    values, lines = [], []
    for line, row in enumerate(rows[1:], start=2):
        if not row or all(not field.strip() for field in row):
            continue
        if len(row) != len(CSV_HEADER):
            raise ValueError(f"{path.name} line {line}: expected {len(CSV_HEADER)} fields, got {len(row)}")
        try:
            values.append([float(field) for field in row])
        except ValueError as error:
            raise ValueError(f"{path.name} line {line}: {error}") from None
        lines.append(line)
    if not values:
        raise ValueError(f"{path.name}: no samples after the header")
    table = np.asarray(values)
    return PoseLog(*_validated_samples(table[:, 0], table[:, 1:], lambda i: f"{path.name} line {lines[i]}"))


def _read_json(path: Path) -> PoseLog:
    try:
        entries = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path.name}: not valid JSON ({error})") from None
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{path.name}: expected a non-empty list of pose samples")
    times, poses = [], []
    for index, entry in enumerate(entries):
        label = f"{path.name} entry {index}"
        if not isinstance(entry, dict) or not {"timestamp_s", "T_world_gripper"} <= entry.keys():
            raise ValueError(f"{label}: expected an object with 'timestamp_s' and 'T_world_gripper'")
        pose = entry["T_world_gripper"]
        if not isinstance(pose, list) or len(pose) != 7:
            raise ValueError(f"{label}: T_world_gripper must be 7 numbers [qw, qx, qy, qz, x_mm, y_mm, z_mm]")
        try:
            times.append(float(entry["timestamp_s"]))
            poses.append([float(value) for value in pose])
        except (TypeError, ValueError) as error:
            raise ValueError(f"{label}: {error}") from None
    return PoseLog(*_validated_samples(times, poses, lambda i: f"{path.name} entry {i}"))


def encode_pose_packet(timestamp_s: float, wxyz_xyz: Sequence[float] | np.ndarray) -> bytes:
    """The 68-byte UDP packet for one pose (format in the module docstring)."""
    values = np.asarray(wxyz_xyz, dtype=np.float64)
    if values.shape != (7,):
        raise ValueError(f"pose must be 7 numbers wxyz + xyz, got shape {values.shape}")
    return struct.pack(PACKET_FORMAT, PACKET_MAGIC, float(timestamp_s), *values.tolist())


def decode_pose_packet(packet: bytes) -> tuple[float, np.ndarray]:
    """(timestamp_s, (7,) wxyz_xyz with the quaternion normalised); ValueError if malformed."""
    if len(packet) != PACKET_SIZE:
        raise ValueError(f"packet has {len(packet)} bytes, expected {PACKET_SIZE}")
    magic, timestamp_s, *pose = struct.unpack(PACKET_FORMAT, packet)
    if magic != PACKET_MAGIC:
        raise ValueError(f"packet starts with {magic!r}, expected {PACKET_MAGIC!r}")
    times, poses = _validated_samples([timestamp_s], [pose], lambda i: "packet")
    return float(times[0]), poses[0]


def send_pose(sock: socket.socket, address: tuple[str, int], sample: PoseSample) -> None:
    """Send one pose sample as a UDP packet (for robot-side scripts and tests)."""
    sock.sendto(encode_pose_packet(sample.timestamp_s, np.asarray(sample.T_world_gripper.wxyz_xyz)), address)


class UdpPoseReceiver:
    """Receives pose packets on a UDP port in a background thread, keeping the newest in a ring.

    Malformed packets (wrong size or magic, non-finite values, non-unit quaternion) and packets
    no newer than the newest kept sample are counted and dropped; the thread never stops on them.

    Args:
        host: interface to bind, e.g. "0.0.0.0" or "127.0.0.1".
        port: UDP port; 0 picks a free one (see ``address``).
        capacity: number of newest samples kept for ``pose_at``.
        timestamps: ``"sender"`` uses the packet's timestamp (the robot must stamp with the
            camera's clock, e.g. the same host's monotonic clock); ``"arrival"`` stamps each
            packet with ``clock()`` on receipt (clocks need not agree; network latency counts
            as skew).
        clock: host clock for arrival times and ``latest``'s age check, seconds.
    """

    def __init__(
        self,
        host: str = "0.0.0.0",
        port: int = 0,
        *,
        capacity: int = 1000,
        timestamps: Literal["sender", "arrival"] = "sender",
        clock: Callable[[], float] = time.monotonic,
    ):
        if timestamps not in ("sender", "arrival"):
            raise ValueError(f"timestamps must be 'sender' or 'arrival', got {timestamps!r}")
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self._timestamps_mode = timestamps
        self._clock = clock
        self._times = np.zeros(capacity)
        self._poses = np.zeros((capacity, 7))
        self._arrivals = np.zeros(capacity)
        self._stored = 0
        self._lock = threading.Lock()
        self.received_packets = 0
        """Packets received, valid or not."""
        self.malformed_packets = 0
        self.out_of_order_packets = 0
        """Valid packets dropped because they were not newer than the newest sample."""
        self.last_error = ""
        """Why the latest rejected packet was rejected."""
        self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._socket.bind((host, port))
        self._socket.settimeout(0.05)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._receive_loop, name="UdpPoseReceiver", daemon=True)
        self._thread.start()

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the receiver is bound to."""
        return self._socket.getsockname()

    def latest(self, max_age_s: float) -> PoseSample:
        """The newest sample; ``StaleDataError`` if none arrived within ``max_age_s`` (host clock)."""
        with self._lock:
            if self._stored == 0:
                raise StaleDataError("robot pose", float("inf"), max_age_s, "no packet received yet")
            slot = (self._stored - 1) % len(self._times)
            age_s = self._clock() - self._arrivals[slot]
            timestamp_s, pose = float(self._times[slot]), self._poses[slot].copy()
        if age_s > max_age_s:
            raise StaleDataError("robot pose", age_s, max_age_s, "newest packet arrived too long ago")
        return PoseSample(timestamp_s=timestamp_s, T_world_gripper=jaxlie.SE3(wxyz_xyz=pose))

    def pose_at(self, timestamp_s: float, *, max_skew_s: float, interpolate: bool = True) -> PoseSample:
        """The pose at ``timestamp_s`` from the kept samples (see the module docstring)."""
        times, poses = self._snapshot()
        return pose_at_time(times, poses, timestamp_s, max_skew_s=max_skew_s, interpolate=interpolate)

    def close(self) -> None:
        """Stop the thread and release the port."""
        self._stop.set()
        self._thread.join()
        self._socket.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def _snapshot(self) -> tuple[np.ndarray, np.ndarray]:
        """Kept samples, oldest first."""
        with self._lock:
            capacity = len(self._times)
            count = min(self._stored, capacity)
            order = (np.arange(count) + self._stored - count) % capacity
            return self._times[order], self._poses[order]

    def _receive_loop(self) -> None:
        while not self._stop.is_set():
            try:
                packet = self._socket.recv(PACKET_SIZE + 1)
            except TimeoutError:
                continue
            except OSError:
                return
            self._accept(packet, self._clock())

    def _accept(self, packet: bytes, arrival_s: float) -> None:
        with self._lock:
            self.received_packets += 1
            try:
                timestamp_s, pose = decode_pose_packet(packet)
            except ValueError as error:
                self.malformed_packets += 1
                self.last_error = str(error)
                return
            if self._timestamps_mode == "arrival":
                timestamp_s = arrival_s
            capacity = len(self._times)
            if self._stored and timestamp_s <= self._times[(self._stored - 1) % capacity]:
                self.out_of_order_packets += 1
                self.last_error = f"packet at {timestamp_s:.6f} s is not newer than the newest sample"
                return
            slot = self._stored % capacity
            self._times[slot], self._poses[slot], self._arrivals[slot] = timestamp_s, pose, arrival_s
            self._stored += 1
