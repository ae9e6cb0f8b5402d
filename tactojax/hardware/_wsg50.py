"""Client for the Weiss WSG-50 parallel-jaw gripper, over a serial port or TCP (pyserial URLs)."""

from __future__ import annotations

import math
import threading
import time
from typing import Literal

import serial

from tactojax.hardware._wsg50_protocol import (
    CommandId,
    Frame,
    FrameParser,
    GraspingState,
    GripperDisconnectedError,
    GripperError,
    GripperProtocolError,
    GripperStatus,
    GripperStatusError,
    GripperTimeoutError,
    command_name,
    encode_frame,
    pack_floats,
    unpack_float,
)

STROKE_MM = 110.0  # WSG-50 jaw opening range, 0 to 110 mm
MAX_SPEED_MM_S = 420.0  # WSG-50 datasheet maximum finger speed
MAX_FORCE_N = 80.0  # WSG-50 datasheet nominal grasping force

_HOMING_DIRECTIONS = {"default": 0, "positive": 1, "negative": 2}
_MOVE_STOP_ON_BLOCK = 0x02  # flag bit 1 of MOVE; bit 0 (relative motion) is not used here
_ANSWER_ONCE = bytes(3)  # GET_* payload: no automatic updates (flags 0, period 0 ms)
_ACKNOWLEDGE_KEY = b"ack"  # ACKNOWLEDGE_FAULT wants these three ASCII bytes

try:  # a hung-up terminal makes pyserial's tcflush raise termios.error, which is no OSError
    import termios

    _PORT_ERRORS: tuple[type[Exception], ...] = (serial.SerialException, OSError, termios.error)
except ImportError:  # Windows
    _PORT_ERRORS = (serial.SerialException, OSError)


class WSG50:
    """A WSG-50 gripper on a serial port (`/dev/ttyUSB0`) or TCP (`socket://192.168.1.20:1000`).

    Commands block until the gripper has finished: motion commands are first acknowledged with
    E_CMD_PENDING and answered again when the jaws stop. Replies are only used once their
    checksum, command id, status and size are verified; anything else raises a `GripperError`.
    One command runs at a time (calls from several threads are serialised).

    Args:
        url: a pyserial URL: a device path, or `socket://host:port`.
        timeout_s: how long to wait for a reply, in s.
        motion_timeout_s: how long a motion may run after its E_CMD_PENDING acknowledgement, in s.
        baudrate: serial bit rate (ignored for TCP).
        stroke_mm: largest jaw opening, in mm.
        max_speed_mm_s: fastest allowed finger speed, in mm/s.
        max_force_n: largest allowed grasping force, in N.
        poll_interval_s: longest single wait on the port while a reply is due, in s.
    """

    def __init__(self, url: str, *, timeout_s: float = 1.0, motion_timeout_s: float = 30.0,
                 baudrate: int = 115200, stroke_mm: float = STROKE_MM,
                 max_speed_mm_s: float = MAX_SPEED_MM_S, max_force_n: float = MAX_FORCE_N,
                 poll_interval_s: float = 0.01):
        for name, value in [("timeout_s", timeout_s), ("motion_timeout_s", motion_timeout_s),
                            ("stroke_mm", stroke_mm), ("max_speed_mm_s", max_speed_mm_s),
                            ("max_force_n", max_force_n), ("poll_interval_s", poll_interval_s)]:
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        self.url = url
        self.timeout_s = timeout_s
        self.motion_timeout_s = motion_timeout_s
        self.stroke_mm = stroke_mm
        self.max_speed_mm_s = max_speed_mm_s
        self.max_force_n = max_force_n
        self._parser = FrameParser()
        self._lock = threading.Lock()
        try:
            self._port = serial.serial_for_url(url, baudrate=baudrate, timeout=poll_interval_s,
                                               write_timeout=timeout_s)
        except (serial.SerialException, OSError, ValueError) as error:
            raise GripperDisconnectedError(f"cannot open the WSG-50 connection {url!r}: {error}") from error

    def __enter__(self) -> WSG50:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    @property
    def is_open(self) -> bool:
        """Whether the connection is open (it may still have broken on the other side)."""
        return self._port.is_open

    def close(self, *, announce: bool = True) -> None:
        """Close the connection; with `announce`, tell the gripper first so that it does not
        treat the lost connection as a fault. Closing twice is harmless."""
        if not self._port.is_open:
            return
        if announce:
            try:
                self._transact(CommandId.DISCONNECT_ANNOUNCEMENT)
            except GripperError:
                pass  # the connection is going away either way
        self._port.close()

    # Motion.

    def home(self, *, direction: Literal["default", "positive", "negative"] = "default") -> None:
        """Reference the jaws by driving them to an end stop; needed once after power-up.

        Args:
            direction: "positive" (opening), "negative" (closing) or the gripper's configured default.
        """
        if direction not in _HOMING_DIRECTIONS:
            raise ValueError(f"direction must be one of {sorted(_HOMING_DIRECTIONS)}, got {direction!r}")
        self._transact(CommandId.HOMING, bytes([_HOMING_DIRECTIONS[direction]]))

    def move(self, width_mm: float, speed_mm_s: float, *, stop_on_block: bool = False,
             wait: bool = True) -> None:
        """Move the jaws to an opening without grasping ("pre-position").

        Args:
            width_mm: target opening, in mm (0 to `stroke_mm`).
            speed_mm_s: finger speed, in mm/s (0 to `max_speed_mm_s`, exclusive of 0).
            stop_on_block: stop at an obstacle instead of pushing against it.
            wait: wait for the motion to end; False returns after the gripper accepted it.

        Raises:
            GripperStatusError: e.g. E_AXIS_BLOCKED when the jaws hit something.
        """
        flags = _MOVE_STOP_ON_BLOCK if stop_on_block else 0
        payload = bytes([flags]) + pack_floats(self._width(width_mm), self._speed(speed_mm_s))
        self._transact(CommandId.MOVE, payload, wait=wait)

    def grasp(self, width_mm: float, speed_mm_s: float, force_n: float | None = None, *,
              wait: bool = True) -> None:
        """Close on a part of nominal width `width_mm` and hold it with the force limit.

        Args:
            width_mm: nominal width of the part, in mm (0 to `stroke_mm`).
            speed_mm_s: finger speed, in mm/s.
            force_n: grasping force limit, in N; None keeps the gripper's current limit.
            wait: wait for the grasp to end; False returns after the gripper accepted it.

        Raises:
            GripperStatusError: E_CMD_FAILED when no part was found between the jaws.
        """
        width_mm, speed_mm_s = self._width(width_mm), self._speed(speed_mm_s)
        if force_n is not None:
            self.set_force_limit(force_n)
        self._transact(CommandId.GRASP, pack_floats(width_mm, speed_mm_s), wait=wait,
                       hint="no part was found between the jaws, or it was lost")

    def release(self, width_mm: float, speed_mm_s: float, *, wait: bool = True) -> None:
        """Release a grasped part by opening the jaws to `width_mm`.

        Args:
            width_mm: opening after the release, in mm (0 to `stroke_mm`).
            speed_mm_s: finger speed, in mm/s.
            wait: wait for the jaws to stop; False returns after the gripper accepted the command.
        """
        payload = pack_floats(self._width(width_mm), self._speed(speed_mm_s))
        self._transact(CommandId.RELEASE, payload, wait=wait)

    def stop(self) -> None:
        """Stop the jaws, e.g. cutting short a motion started with `wait=False`."""
        self._transact(CommandId.STOP)

    def fast_stop(self) -> None:
        """Emergency stop: the gripper refuses motion until `acknowledge_fault` is called."""
        self._transact(CommandId.FAST_STOP)

    def acknowledge_fault(self) -> None:
        """Clear a fast stop or fault so that the gripper accepts motion commands again."""
        self._transact(CommandId.ACKNOWLEDGE_FAULT, _ACKNOWLEDGE_KEY)

    def set_force_limit(self, force_n: float) -> None:
        """Set the grasping force limit used by later grasps, in N (0 to `max_force_n`)."""
        force_n = _in_range("force_n", force_n, 0.0, self.max_force_n, "N", low_allowed=False)
        self._transact(CommandId.SET_FORCE_LIMIT, pack_floats(force_n))

    # Queries.

    def opening_mm(self) -> float:
        """The current jaw opening, in mm."""
        return self._query_float(CommandId.GET_OPENING_WIDTH)

    def force_n(self) -> float:
        """The current grasping force, in N."""
        return self._query_float(CommandId.GET_FORCE)

    def grasping_state(self) -> GraspingState:
        """The gripper's grasping state (IDLE, HOLDING, NO_PART_FOUND, ...)."""
        parameters = self._transact(CommandId.GET_GRASPING_STATE, _ANSWER_ONCE)
        if len(parameters) != 1:
            raise GripperProtocolError(f"grasping state reply has {len(parameters)} bytes, expected 1")
        try:
            return GraspingState(parameters[0])
        except ValueError:
            raise GripperProtocolError(f"unknown grasping state {parameters[0]}") from None

    # Internals.

    def _width(self, width_mm: float) -> float:
        return _in_range("width_mm", width_mm, 0.0, self.stroke_mm, "mm")

    def _speed(self, speed_mm_s: float) -> float:
        return _in_range("speed_mm_s", speed_mm_s, 0.0, self.max_speed_mm_s, "mm/s", low_allowed=False)

    def _query_float(self, command_id: CommandId) -> float:
        value = unpack_float(self._transact(command_id, _ANSWER_ONCE))
        if not math.isfinite(value):
            raise GripperProtocolError(f"{command_name(command_id)} returned {value}")
        return value

    def _transact(self, command_id: CommandId, payload: bytes = b"", *, wait: bool = True,
                  hint: str = "") -> bytes:
        """Send one command and return the parameters of its final successful reply."""
        with self._lock:
            self._discard_stale_input()
            self._write(encode_frame(command_id, payload))
            deadline = time.monotonic() + self.timeout_s
            while True:
                frame = self._read_frame(deadline, command_id)
                if frame.command_id != command_id:
                    continue  # a late reply to an earlier command, e.g. a motion ended by stop()
                status = frame.status()
                if status == GripperStatus.E_CMD_PENDING:
                    if not wait:
                        return frame.parameters()
                    deadline = time.monotonic() + self.motion_timeout_s
                    continue
                if status == GripperStatus.E_CMD_FAILED:
                    raise GripperStatusError(command_id, status, hint)
                if status != GripperStatus.E_SUCCESS:
                    raise GripperStatusError(command_id, status)
                return frame.parameters()

    def _read_frame(self, deadline: float, command_id: int) -> Frame:
        while (frame := self._parser.next_frame()) is None:
            if time.monotonic() >= deadline:
                raise GripperTimeoutError(
                    f"no complete reply to {command_name(command_id)} from {self.url} in time "
                    f"({self._parser.buffered} bytes of a partial frame received)")
            self._parser.feed(self._read_available())
        return frame

    def _discard_stale_input(self) -> None:
        self._ensure_open()
        self._parser.clear()
        try:
            self._port.reset_input_buffer()
        except _PORT_ERRORS as error:
            raise GripperDisconnectedError(f"WSG-50 connection {self.url} broke: {error}") from error

    def _read_available(self) -> bytes:
        try:
            return self._port.read(max(1, self._port.in_waiting))
        except _PORT_ERRORS as error:
            raise GripperDisconnectedError(f"WSG-50 connection {self.url} broke: {error}") from error

    def _write(self, message: bytes) -> None:
        try:
            self._port.write(message)
        except serial.SerialTimeoutException as error:
            raise GripperTimeoutError(f"could not send to {self.url} in {self.timeout_s} s") from error
        except _PORT_ERRORS as error:
            raise GripperDisconnectedError(f"WSG-50 connection {self.url} broke: {error}") from error

    def _ensure_open(self) -> None:
        if not self._port.is_open:
            raise GripperDisconnectedError(f"the WSG-50 connection {self.url} is closed")


def _in_range(name: str, value: float, low: float, high: float, unit: str, *,
              low_allowed: bool = True) -> float:
    """`value` as a float after checking low <= value <= high (low < value without `low_allowed`)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a number in {unit}, got {value!r}") from None
    above_low = number >= low if low_allowed else number > low
    if not (above_low and number <= high):  # also rejects nan
        bracket = "[" if low_allowed else "("
        raise ValueError(f"{name} must be in {bracket}{low:g}, {high:g}] {unit}, got {value!r}")
    return number
