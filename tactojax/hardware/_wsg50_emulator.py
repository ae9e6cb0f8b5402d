"""An in-process WSG-50 emulator that speaks the binary protocol over a pseudo-terminal or TCP.

Meant for tests and dry runs of `WSG50`: jaws move at the commanded speed (instantly with
`time_scale=0`), a grasp stops on `object_width_mm` (None: nothing between the jaws), and
faults can be injected into the next reply frames (bad checksum, dropped reply, garbage,
split writes, a connection that breaks mid-reply) or the next commands (an error status).
"""

from __future__ import annotations

import collections
import dataclasses
import enum
import os
import select
import socket
import struct
import threading
import time

from tactojax.hardware._wsg50_protocol import (
    CommandId,
    Frame,
    FrameParser,
    GraspingState,
    GripperProtocolError,
    GripperStatus,
    encode_frame,
    pack_floats,
)

GARBAGE = b"\x00\x13\xaa\x55\xaa\xaa\x42\xff\xaa"  # noise with partial preambles, ending in 0xAA
_POLL_S = 0.02  # longest wait for input while serving, in s
_SPLIT_PAUSE_S = 0.005  # pause between the parts of a split reply, in s


class EmulatorFault(enum.Enum):
    """Faults the emulator can inject into its next reply frame."""

    CORRUPT_CHECKSUM = "corrupt_checksum"  # flip bits of the frame's checksum
    CORRUPT_PAYLOAD = "corrupt_payload"  # flip one bit of the frame's last payload byte
    DROP_REPLY = "drop_reply"  # never send the frame
    GARBAGE_BEFORE_REPLY = "garbage_before_reply"  # send `GARBAGE` first
    SPLIT_REPLY = "split_reply"  # send the frame in three writes, a few ms apart
    DISCONNECT_MID_REPLY = "disconnect_mid_reply"  # send half the frame, then break the connection


class _HangUp(Exception):
    """Raised inside the serving thread to break the connection."""


@dataclasses.dataclass(frozen=True)
class _Motion:
    """A jaw motion in progress and what it ends in."""

    command_id: int
    start_width_mm: float
    end_width_mm: float
    start_time: float
    duration_s: float
    final_status: GripperStatus
    final_state: GraspingState
    final_force_n: float

    def width_at(self, now: float) -> float:
        if self.duration_s <= 0 or now >= self.start_time + self.duration_s:
            return self.end_width_mm
        fraction = (now - self.start_time) / self.duration_s
        return self.start_width_mm + fraction * (self.end_width_mm - self.start_width_mm)


class _PtyChannel:
    def __init__(self):
        import tty  # POSIX only

        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)  # no echo, no newline translation
        self.path = os.ttyname(self.slave)

    def receive(self, timeout_s: float) -> bytes | None:
        ready, _, _ = select.select([self.master], [], [], timeout_s)
        return os.read(self.master, 4096) if ready else b""

    def send(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(self.master, view):]

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


class _SocketChannel:
    def __init__(self, connection: socket.socket):
        self.connection = connection
        connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def receive(self, timeout_s: float) -> bytes | None:
        ready, _, _ = select.select([self.connection], [], [], timeout_s)
        if not ready:
            return b""
        try:
            data = self.connection.recv(4096)
        except OSError:
            return None
        return data or None  # b"": the client closed the connection

    def send(self, data: bytes) -> None:
        self.connection.sendall(data)

    def close(self) -> None:
        try:
            self.connection.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.connection.close()


class WSG50Emulator:
    """A simulated WSG-50 that answers `WSG50` over a pseudo-terminal or loopback TCP.

    Start it with `serve_pty()` or `serve_tcp()`, which return what to pass to `WSG50(...)`;
    stop it with `close()` (or use it as a context manager). Attributes may be changed from the
    test while it serves, e.g. `emulator.object_width_mm = 40.0`.

    Args:
        stroke_mm: largest jaw opening, in mm.
        max_speed_mm_s: fastest accepted finger speed, in mm/s.
        max_force_n: largest accepted force limit, in N.
        width_mm: jaw opening at power-up, in mm.
        time_scale: motion time relative to real time (0: instant, 1: real speed).
        clamping_travel_mm: how far past the nominal width a grasp looks for the part, in mm.
        homing_speed_mm_s: finger speed while homing, in mm/s.
        require_homing: refuse motion with E_NOT_INITIALIZED until homed, like the real gripper.

    Attributes:
        object_width_mm: width of the object between the jaws, in mm; None for no object.
        force_limit_n: grasping force limit, in N.
        commands_received: ids of all commands received, oldest first.
        replies_sent: (command id, status) of all replies sent or dropped, oldest first.
    """

    def __init__(self, *, stroke_mm: float = 110.0, max_speed_mm_s: float = 420.0,
                 max_force_n: float = 80.0, width_mm: float = 55.0, time_scale: float = 0.0,
                 clamping_travel_mm: float = 10.0, homing_speed_mm_s: float = 100.0,
                 require_homing: bool = True):
        self.stroke_mm = stroke_mm
        self.max_speed_mm_s = max_speed_mm_s
        self.max_force_n = max_force_n
        self.time_scale = time_scale
        self.clamping_travel_mm = clamping_travel_mm
        self.homing_speed_mm_s = homing_speed_mm_s
        self.object_width_mm: float | None = None
        self.force_limit_n = max_force_n / 2
        self.homed = not require_homing
        self.fast_stopped = False
        self.grasping_state = GraspingState.IDLE
        self.commands_received: list[int] = []
        self.replies_sent: list[tuple[int, GripperStatus]] = []
        self._width_mm = width_mm
        self._force_n = 0.0
        self._motion: _Motion | None = None
        self._faults: collections.deque[EmulatorFault] = collections.deque()
        self._error_statuses: collections.deque[GripperStatus] = collections.deque()
        self._outbox: collections.deque[tuple[int, GripperStatus, bytes]] = collections.deque()
        self._lock = threading.RLock()
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._listener: socket.socket | None = None
        self._pty: _PtyChannel | None = None

    # Control from the test.

    def serve_pty(self) -> str:
        """Serve on a new pseudo-terminal in a background thread; returns its device path."""
        self._pty = _PtyChannel()
        self._start(self._serve_pty_forever)
        return self._pty.path

    def serve_tcp(self) -> str:
        """Serve on a free loopback TCP port in a background thread; returns `socket://127.0.0.1:PORT`."""
        self._listener = socket.create_server(("127.0.0.1", 0))
        self._start(self._serve_tcp_forever)
        return f"socket://127.0.0.1:{self._listener.getsockname()[1]}"

    def close(self) -> None:
        """Stop serving and release the port or terminal."""
        self._stopping.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        if self._listener is not None:
            self._listener.close()
        if self._pty is not None:
            self._pty.close()

    def __enter__(self) -> WSG50Emulator:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def inject_fault(self, fault: EmulatorFault, count: int = 1) -> None:
        """Apply `fault` to the next `count` reply frames (an E_CMD_PENDING ack is a frame too)."""
        self._faults.extend([fault] * count)

    def inject_error_status(self, status: GripperStatus) -> None:
        """Answer the next command with `status` instead of carrying it out."""
        self._error_statuses.append(status)

    @property
    def width_mm(self) -> float:
        """The current jaw opening, in mm (moving jaws included)."""
        with self._lock:
            motion = self._motion
            return motion.width_at(time.monotonic()) if motion else self._width_mm

    @property
    def force_n(self) -> float:
        """The current grasping force, in N."""
        return self._force_n

    # Serving.

    def _start(self, target) -> None:
        if self._thread is not None:
            raise RuntimeError("the emulator is already serving; create another one")
        self._thread = threading.Thread(target=target, name="wsg50-emulator", daemon=True)
        self._thread.start()

    def _serve_pty_forever(self) -> None:
        try:
            self._serve_connection(self._pty)
        except (_HangUp, OSError):
            self._pty.close()  # the terminal hangs up for good, like an unplugged adapter

    def _serve_tcp_forever(self) -> None:
        self._listener.settimeout(_POLL_S)
        while not self._stopping.is_set():
            try:
                connection, _ = self._listener.accept()
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return  # listener closed
            channel = _SocketChannel(connection)
            try:
                self._serve_connection(channel)
            except (_HangUp, OSError):
                pass
            finally:
                channel.close()

    def _serve_connection(self, channel) -> None:
        parser = FrameParser()
        with self._lock:
            self._outbox.clear()  # replies meant for a previous connection
        while not self._stopping.is_set():
            data = channel.receive(self._wait_s())
            if data is None:
                return
            parser.feed(data)
            while True:
                try:
                    frame = parser.next_frame()
                except GripperProtocolError:
                    continue  # a corrupted command is ignored; the client will time out
                if frame is None:
                    break
                with self._lock:
                    self._handle(frame, channel)
            with self._lock:
                self._finish_motion_if_due()
                self._flush(channel)

    def _wait_s(self) -> float:
        motion = self._motion
        if motion is None:
            return _POLL_S
        remaining = motion.start_time + motion.duration_s - time.monotonic()
        return min(_POLL_S, max(remaining, 0.0))

    def _flush(self, channel) -> None:
        """Send the queued replies, oldest first."""
        while self._outbox:
            self._send(channel, *self._outbox.popleft())

    def _send(self, channel, command_id: int, status: GripperStatus, parameters: bytes = b"") -> None:
        self.replies_sent.append((command_id, GripperStatus(status)))
        message = encode_frame(command_id, struct.pack("<H", status) + parameters)
        fault = self._faults.popleft() if self._faults else None
        if fault is EmulatorFault.DROP_REPLY:
            return
        if fault is EmulatorFault.CORRUPT_CHECKSUM:
            message = message[:-2] + bytes([message[-2] ^ 0x5A, message[-1] ^ 0xA5])
        if fault is EmulatorFault.CORRUPT_PAYLOAD:
            message = message[:-3] + bytes([message[-3] ^ 0x01]) + message[-2:]
        if fault is EmulatorFault.GARBAGE_BEFORE_REPLY:
            channel.send(GARBAGE)
        if fault is EmulatorFault.DISCONNECT_MID_REPLY:
            channel.send(message[: len(message) // 2])
            raise _HangUp
        if fault is EmulatorFault.SPLIT_REPLY:
            third = len(message) // 3
            for part in (message[:third], message[third:2 * third], message[2 * third:]):
                channel.send(part)
                time.sleep(_SPLIT_PAUSE_S)
            return
        channel.send(message)

    # Commands.

    def _handle(self, frame: Frame, channel) -> None:
        self.commands_received.append(frame.command_id)
        self._finish_motion_if_due()
        if self._error_statuses:
            self._outbox.append((frame.command_id, self._error_statuses.popleft(), b""))
        else:
            handler = {
                CommandId.LOOP: self._loop,
                CommandId.DISCONNECT_ANNOUNCEMENT: self._no_parameters,
                CommandId.HOMING: self._home,
                CommandId.MOVE: self._move,
                CommandId.STOP: self._stop,
                CommandId.FAST_STOP: self._stop,
                CommandId.ACKNOWLEDGE_FAULT: self._acknowledge_fault,
                CommandId.GRASP: self._grasp,
                CommandId.RELEASE: self._release,
                CommandId.SET_FORCE_LIMIT: self._set_force_limit,
                CommandId.GET_FORCE_LIMIT: self._get_value,
                CommandId.GET_GRASPING_STATE: self._get_value,
                CommandId.GET_OPENING_WIDTH: self._get_value,
                CommandId.GET_FORCE: self._get_value,
            }.get(frame.command_id, self._unknown)
            reply = handler(frame.command_id, frame.payload)
            if reply is not None:  # None: a motion started and queued its own acknowledgement
                self._outbox.append((frame.command_id, *reply))
            self._finish_motion_if_due()
        self._flush(channel)

    def _unknown(self, command_id: int, payload: bytes):
        return GripperStatus.E_CMD_UNKNOWN, b""

    def _loop(self, command_id: int, payload: bytes):
        return GripperStatus.E_SUCCESS, payload

    def _no_parameters(self, command_id: int, payload: bytes):
        return (GripperStatus.E_NO_PARAM_EXPECTED if payload else GripperStatus.E_SUCCESS), b""

    def _stop(self, command_id: int, payload: bytes):
        if payload:
            return GripperStatus.E_NO_PARAM_EXPECTED, b""
        self._abort_motion()
        if command_id == CommandId.FAST_STOP:
            self.fast_stopped = True
            self.grasping_state = GraspingState.ERROR
        return GripperStatus.E_SUCCESS, b""

    def _acknowledge_fault(self, command_id: int, payload: bytes):
        if payload != b"ack":
            return GripperStatus.E_CMD_FORMAT_ERROR, b""
        self.fast_stopped = False
        self.grasping_state = GraspingState.IDLE
        return GripperStatus.E_SUCCESS, b""

    def _set_force_limit(self, command_id: int, payload: bytes):
        if len(payload) != 4:
            return GripperStatus.E_CMD_FORMAT_ERROR, b""
        (force_n,) = struct.unpack("<f", payload)
        if not 0 < force_n <= self.max_force_n:
            return GripperStatus.E_RANGE_ERROR, b""
        self.force_limit_n = force_n
        return GripperStatus.E_SUCCESS, b""

    def _get_value(self, command_id: int, payload: bytes):
        if len(payload) != 3:
            return GripperStatus.E_CMD_FORMAT_ERROR, b""
        if payload[0] & 0x01:
            return GripperStatus.E_FEATURE_NOT_SUPPORTED, b""  # automatic updates are not emulated
        if command_id == CommandId.GET_GRASPING_STATE:
            return GripperStatus.E_SUCCESS, bytes([self.grasping_state])
        value = {CommandId.GET_OPENING_WIDTH: self.width_mm, CommandId.GET_FORCE: self._force_n,
                 CommandId.GET_FORCE_LIMIT: self.force_limit_n}[command_id]
        return GripperStatus.E_SUCCESS, pack_floats(value)

    def _home(self, command_id: int, payload: bytes):
        if len(payload) != 1 or payload[0] not in (0, 1, 2):
            return GripperStatus.E_CMD_FORMAT_ERROR, b""
        if refusal := self._refuse_motion(require_homed=False):
            return refusal, b""
        self.homed = True
        target_mm = 0.0 if payload[0] == 2 else self.stroke_mm
        return self._start_motion(command_id, target_mm, self.homing_speed_mm_s, GripperStatus.E_SUCCESS,
                                  GraspingState.POSITIONING, GraspingState.IDLE)

    def _move(self, command_id: int, payload: bytes):
        if len(payload) != 9:
            return GripperStatus.E_CMD_FORMAT_ERROR, b""
        flags, (width_mm, speed_mm_s) = payload[0], struct.unpack("<2f", payload[1:])
        if flags & 0x01:  # relative motion
            width_mm += self.width_mm
        if refusal := self._refuse_motion() or self._check_width_speed(width_mm, speed_mm_s):
            return refusal, b""
        status, end_mm = GripperStatus.E_SUCCESS, width_mm
        if self._object_between(end_mm, self.width_mm):
            status, end_mm = GripperStatus.E_AXIS_BLOCKED, self.object_width_mm
        return self._start_motion(command_id, end_mm, speed_mm_s, status, GraspingState.POSITIONING,
                                  GraspingState.IDLE)

    def _grasp(self, command_id: int, payload: bytes):
        if len(payload) != 8:
            return GripperStatus.E_CMD_FORMAT_ERROR, b""
        width_mm, speed_mm_s = struct.unpack("<2f", payload)
        if refusal := self._refuse_motion() or self._check_width_speed(width_mm, speed_mm_s):
            return refusal, b""
        deepest_mm = max(width_mm - self.clamping_travel_mm, 0.0)
        if not self._object_between(deepest_mm, self.width_mm):
            return self._start_motion(command_id, deepest_mm, speed_mm_s, GripperStatus.E_CMD_FAILED,
                                      GraspingState.GRASPING, GraspingState.NO_PART_FOUND)
        if self.object_width_mm > width_mm + self.clamping_travel_mm:  # hit before the clamping travel
            return self._start_motion(command_id, self.object_width_mm, speed_mm_s,
                                      GripperStatus.E_AXIS_BLOCKED, GraspingState.GRASPING,
                                      GraspingState.ERROR)
        return self._start_motion(command_id, self.object_width_mm, speed_mm_s, GripperStatus.E_SUCCESS,
                                  GraspingState.GRASPING, GraspingState.HOLDING, self.force_limit_n)

    def _release(self, command_id: int, payload: bytes):
        if len(payload) != 8:
            return GripperStatus.E_CMD_FORMAT_ERROR, b""
        width_mm, speed_mm_s = struct.unpack("<2f", payload)
        if refusal := self._refuse_motion() or self._check_width_speed(width_mm, speed_mm_s):
            return refusal, b""
        if width_mm < self.width_mm:
            return GripperStatus.E_RANGE_ERROR, b""  # a release opens the jaws
        self._force_n = 0.0
        return self._start_motion(command_id, width_mm, speed_mm_s, GripperStatus.E_SUCCESS,
                                  GraspingState.RELEASING, GraspingState.IDLE)

    # Physics.

    def _refuse_motion(self, *, require_homed: bool = True) -> GripperStatus | None:
        if self._motion is not None:
            return GripperStatus.E_ALREADY_RUNNING
        if self.fast_stopped:
            return GripperStatus.E_ACCESS_DENIED
        if require_homed and not self.homed:
            return GripperStatus.E_NOT_INITIALIZED
        return None

    def _check_width_speed(self, width_mm: float, speed_mm_s: float) -> GripperStatus | None:
        if not (0.0 <= width_mm <= self.stroke_mm and 0.0 < speed_mm_s <= self.max_speed_mm_s):
            return GripperStatus.E_RANGE_ERROR
        return None

    def _object_between(self, closing_to_mm: float, opening_mm: float) -> bool:
        """Whether closing the jaws from `opening_mm` to `closing_to_mm` meets the object."""
        width = self.object_width_mm
        return width is not None and closing_to_mm < width <= opening_mm

    def _start_motion(self, command_id: int, end_width_mm: float, speed_mm_s: float,
                      final_status: GripperStatus, state_during: GraspingState, final_state: GraspingState,
                      final_force_n: float = 0.0) -> None:
        """Start moving the jaws and acknowledge with E_CMD_PENDING; the final reply follows."""
        start_mm = self.width_mm
        self._motion = _Motion(command_id, start_mm, end_width_mm, time.monotonic(),
                               abs(end_width_mm - start_mm) / speed_mm_s * self.time_scale,
                               final_status, final_state, final_force_n)
        self.grasping_state = state_during
        self._outbox.append((command_id, GripperStatus.E_CMD_PENDING, b""))

    def _finish_motion_if_due(self) -> None:
        motion = self._motion
        if motion is None or time.monotonic() < motion.start_time + motion.duration_s:
            return
        self._motion = None
        self._width_mm, self.grasping_state, self._force_n = (
            motion.end_width_mm, motion.final_state, motion.final_force_n)
        self._outbox.append((motion.command_id, motion.final_status, b""))

    def _abort_motion(self) -> None:
        """Stop the jaws where they are; the stopped command ends with E_CMD_ABORTED."""
        motion = self._motion
        if motion is None:
            return
        self._width_mm = motion.width_at(time.monotonic())
        self._motion = None
        self.grasping_state = GraspingState.IDLE
        self._outbox.append((motion.command_id, GripperStatus.E_CMD_ABORTED, b""))
