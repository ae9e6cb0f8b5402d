"""A simulated robot cell: the object, the arm, the tactile camera, and the gripper's physics.

The simulated world (:class:`SimulatedScene`) holds one fixed object and the tactile sensor.
It plays the physical parts of a real cell: when the simulated robot closes the jaws, the scene
runs the grasp simulation (:func:`tactojax.simulate.simulate_grasps`: jaws stop on the object,
the gel is indented, the compliant wrist centres the gripper), tells the gripper *emulator*
where the jaws stop (so the opening comes back through the gripper's own protocol), shows the
rendered tactile image to the :class:`SimulatedCamera` (one per finger with a gel: with
``fingers=2`` the opposite jaw carries a sensor too), and reports the arm's settled pose to
whoever listens (e.g. a UDP pose publisher), exactly as a real cell's devices would.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.hardware._camera import Camera, CameraError, Frame
from tactojax.hardware._pose_source import PoseSample, UdpPoseReceiver, send_pose
from tactojax.hardware._wsg50 import WSG50
from tactojax.hardware._wsg50_emulator import WSG50Emulator
from tactojax.objects import TactileObject
from tactojax.sensor import SensorSpec, render_image
from tactojax.simulate import GraspConfig, simulate_grasps, simulate_two_sensor_grasps


def _to_uint8(image: jax.Array) -> np.ndarray:
    return np.asarray(jnp.round(jnp.clip(image, 0.0, 1.0) * 255.0)).astype(np.uint8)


class SimulatedScene:
    """One object fixed in the world, touched by a simulated gripper with a tactile sensor.

    Thread-safe: the camera and the pose feed may read it from other threads.

    Args:
        spec: the tactile sensor.
        obj: the object.
        T_world_object: its pose, mm (change it with :meth:`place_object`, as an operator turns it).
        config: gripper and contact settings of the simulator.
        seed: seed of the simulated sensor noise.
        fingers: jaws with a gel sensor: 1 (the sensor jaw; a rigid opposite pad) or 2 (both,
            :func:`tactojax.simulate.simulate_two_sensor_grasps`).
    """

    def __init__(self, spec: SensorSpec, obj: TactileObject, T_world_object: jaxlie.SE3 | None = None, *,
                 config: GraspConfig = GraspConfig(), seed: int = 0, fingers: int = 1):
        if fingers not in (1, 2):
            raise ValueError(f"fingers must be 1 or 2, got {fingers}")
        self.spec, self.object, self.config, self.fingers = spec, obj, config, fingers
        self.T_world_object = jaxlie.SE3.identity() if T_world_object is None else T_world_object
        self._key = jax.random.key(seed)
        self._grasps = 0
        self._lock = threading.Lock()
        simulate = simulate_grasps if fingers == 1 else simulate_two_sensor_grasps
        self._simulate = jax.jit(lambda key, T_wo, T_wg: simulate(key, spec, obj, T_wo, T_wg, config))
        self._background = _to_uint8(render_image(spec, jnp.zeros(spec.shape)))
        self._images = (self._background,) * fingers
        self._T_world_gripper = jaxlie.SE3.identity()
        self._listeners: list[Callable[[float, jaxlie.SE3], None]] = []

    def place_object(self, T_world_object: jaxlie.SE3) -> None:
        """Put the object at a new pose (the protocol's turns), mm."""
        with self._lock:
            self.T_world_object = T_world_object

    def on_pose(self, listener: Callable[[float, jaxlie.SE3], None]) -> None:
        """Call ``listener(timestamp_s, T_world_gripper)`` whenever the arm settles at a pose."""
        self._listeners.append(listener)

    def _settle(self, T_world_gripper: jaxlie.SE3) -> None:
        with self._lock:
            self._T_world_gripper = T_world_gripper
            stamp = time.monotonic()
        for listener in self._listeners:
            listener(stamp, T_world_gripper)

    def pose_sample(self) -> tuple[float, jaxlie.SE3]:
        """(monotonic time, T_world_gripper) read together: a pose stamped after a move is the new one."""
        with self._lock:
            return time.monotonic(), self._T_world_gripper

    def move_gripper(self, T_world_gripper: jaxlie.SE3) -> None:
        """The arm moves the open gripper to ``T_world_gripper`` (mm)."""
        self._settle(T_world_gripper)

    def close_jaws(self) -> float | None:
        """Simulate the grasp at the current pose: the opening at contact (mm), or None (a miss)."""
        with self._lock:
            key = jax.random.fold_in(self._key, self._grasps)
            self._grasps += 1
            T_world_gripper = jaxlie.SE3(self._T_world_gripper.wxyz_xyz[None])
            result = jax.device_get(self._simulate(key, self.T_world_object, T_world_gripper))
        if not bool(result.valid[0]):
            return None
        # The first grasp of the batch, its fingers as a leading axis (one finger: add it).
        imprint = jax.tree.map(lambda x: x[0] if self.fingers == 2 else x, result.imprint)
        with self._lock:
            self._images = tuple(_to_uint8(image) for image in imprint.image)
        self._settle(jaxlie.SE3(jnp.asarray(imprint.T_world_gripper.wxyz_xyz[0])))  # wrist compliance
        return float(imprint.opening[0])

    def open_jaws(self) -> None:
        """Let go: the gels show no contact."""
        with self._lock:
            self._images = (self._background,) * self.fingers

    def finger_image(self, finger: int = 0) -> np.ndarray:
        """What finger ``finger``'s tactile camera sees now (0: the sensor jaw, 1: the opposite
        jaw of a two-sensor scene): (H, W, 3) uint8 RGB, rectified."""
        with self._lock:
            return self._images[finger]

    @property
    def image(self) -> np.ndarray:
        """What the sensor jaw's tactile camera sees now: (H, W, 3) uint8 RGB, rectified."""
        return self.finger_image(0)

    @property
    def T_world_gripper(self) -> jaxlie.SE3:
        """Where the arm holds the gripper now, mm."""
        with self._lock:
            return self._T_world_gripper


class SimulatedRobot:
    """A :class:`Robot` on a :class:`SimulatedScene`, with its gripper behind a real protocol.

    The gripper is any client with ``grasp(width_mm, speed_mm_s)``, ``release(width_mm,
    speed_mm_s)`` and ``opening_mm()`` (a :class:`~tactojax.hardware.WSG50` talking to a
    :class:`~tactojax.hardware.WSG50Emulator`); ``emulator`` is that emulator, the gripper's
    physics in the simulation: the scene tells it where the jaws meet the object.

    Args:
        scene: the simulated world.
        gripper: the gripper client.
        emulator: the emulated gripper the client talks to.
        speed_mm_s: jaw speed for grasps and releases, mm/s.
    """

    def __init__(self, scene: SimulatedScene, gripper, emulator, *, speed_mm_s: float = 100.0):
        self.scene, self.gripper, self.emulator, self.speed_mm_s = scene, gripper, emulator, speed_mm_s

    def move_to(self, T_world_gripper: jaxlie.SE3) -> None:
        self.scene.move_gripper(T_world_gripper)

    def grasp(self) -> float | None:
        opening = self.scene.close_jaws()
        self.emulator.object_width_mm = opening
        if opening is None:
            self.scene.open_jaws()
            return None
        self.gripper.grasp(max(opening - 1.0, 0.0), self.speed_mm_s)
        return self.gripper.opening_mm()

    def release(self) -> None:
        self.scene.open_jaws()
        self.emulator.object_width_mm = None
        self.gripper.release(self.scene.config.max_opening_mm, self.speed_mm_s)


class SimulatedCamera(Camera):
    """The tactile camera of a :class:`SimulatedScene`: its current image at a fixed frame rate.

    Like a live USB camera, ``read()`` waits for the next frame time and stamps the frame with
    the host's monotonic clock (the scene's pose feed uses the same clock).

    Args:
        scene: the simulated world.
        fps: frame rate, frames per second; None returns a frame at once on every read.
        finger: the finger whose gel it watches (1: the opposite jaw of a two-sensor scene).
    """

    def __init__(self, scene: SimulatedScene, *, fps: float | None = 30.0, finger: int = 0):
        if fps is not None and not fps > 0:
            raise ValueError(f"fps must be positive, got {fps}")
        if not 0 <= finger < scene.fingers:
            raise ValueError(f"the scene has {scene.fingers} finger(s) with a sensor; no finger {finger}")
        self.scene, self.fps, self.finger = scene, fps, finger
        self._index = 0
        self._next_s = time.monotonic()
        self._closed = False

    @property
    def dropped_frames(self) -> int:
        return 0

    def read(self) -> Frame:
        if self._closed:
            raise CameraError("the simulated camera is closed")
        if self.fps is not None:
            delay = self._next_s - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            self._next_s = max(self._next_s + 1.0 / self.fps, time.monotonic())
        frame = Frame(image=self.scene.finger_image(self.finger), timestamp_s=time.monotonic(), index=self._index)
        self._index += 1
        return frame

    def close(self) -> None:
        self._closed = True


class PosePublisher:
    """Streams a scene's gripper pose as UDP pose packets at a fixed rate, as a robot controller does.

    Besides the periodic stream, every move is sent the moment the arm settles, so the feed
    never interpolates across a jump (the simulated arm moves instantly). Timestamps are the
    host's monotonic clock, as the simulated camera's.

    Args:
        scene: the simulated world.
        address: (host, port) of the receiver.
        rate_hz: packets per second.
    """

    def __init__(self, scene: SimulatedScene, address: tuple[str, int], *, rate_hz: float = 200.0):
        self.scene, self.address, self.period_s = scene, address, 1.0 / rate_hz
        self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        scene.on_pose(self._send)
        self._thread = threading.Thread(target=self._run, name="tactojax-pose-publisher", daemon=True)
        self._thread.start()

    def _send(self, timestamp_s: float, pose: jaxlie.SE3) -> None:
        if self._stop.is_set():
            return
        sample = PoseSample(timestamp_s=timestamp_s, T_world_gripper=jaxlie.SE3(np.asarray(pose.wxyz_xyz, np.float64)))
        with self._send_lock:
            send_pose(self._socket, self.address, sample)

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self._send(*self.scene.pose_sample())

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._socket.close()


@dataclass
class SimulatedCell:
    """A whole simulated robot cell, each device behind the interface its real one has."""

    scene: SimulatedScene
    robot: SimulatedRobot
    camera: SimulatedCamera
    gripper: WSG50
    """The gripper client, talking the WSG-50 protocol to ``emulator``."""
    emulator: WSG50Emulator
    poses: UdpPoseReceiver
    """The robot's pose feed, received over UDP from ``publisher``."""
    publisher: PosePublisher
    second_camera: SimulatedCamera | None = None
    """The opposite finger's camera (``fingers=2``), else None."""


@contextlib.contextmanager
def simulated_cell(spec: SensorSpec, obj: TactileObject, *, transport: str = "tcp", fps: float | None = None,
                   pose_rate_hz: float = 200.0, config: GraspConfig = GraspConfig(), seed: int = 0,
                   fingers: int = 1) -> Iterator[SimulatedCell]:
    """Start a simulated cell: scene, WSG-50 emulator and client, UDP pose feed, camera(s), robot.

    Args:
        spec, obj, config, seed, fingers: the simulated world (see :class:`SimulatedScene`);
            with ``fingers=2`` the cell has a ``second_camera`` on the opposite jaw.
        transport: how the gripper client reaches the emulator: ``"tcp"`` (``socket://``) or
            ``"pty"`` (a pseudo-terminal, as a USB serial port).
        fps: camera frame rate (None: a frame on every read).
        pose_rate_hz: rate of the robot's pose packets.

    Yields:
        the :class:`SimulatedCell`; everything is stopped on exit.
    """
    if transport not in ("tcp", "pty"):
        raise ValueError(f"transport must be 'tcp' or 'pty', got {transport!r}")
    with contextlib.ExitStack() as stack:
        scene = SimulatedScene(spec, obj, config=config, seed=seed, fingers=fingers)
        emulator = stack.enter_context(WSG50Emulator(stroke_mm=config.max_opening_mm,
                                                     width_mm=config.max_opening_mm))
        url = emulator.serve_tcp() if transport == "tcp" else emulator.serve_pty()
        gripper = stack.enter_context(WSG50(url))
        gripper.home()
        poses = stack.enter_context(UdpPoseReceiver("127.0.0.1", 0))
        publisher = PosePublisher(scene, poses.address, rate_hz=pose_rate_hz)
        stack.callback(publisher.close)
        camera = stack.enter_context(SimulatedCamera(scene, fps=fps))
        second_camera = stack.enter_context(SimulatedCamera(scene, fps=fps, finger=1)) if fingers == 2 else None
        robot = SimulatedRobot(scene, gripper, emulator)
        yield SimulatedCell(scene=scene, robot=robot, camera=camera, gripper=gripper, emulator=emulator,
                            poses=poses, publisher=publisher, second_camera=second_camera)
