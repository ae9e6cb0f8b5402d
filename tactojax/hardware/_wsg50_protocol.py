"""Framing of the Weiss WSG-50 binary command protocol, and the gripper exceptions.

A message, in both directions (WSG Command Set Reference, section "Command Message Format"):

    AA AA AA | id (1 byte) | payload size (uint16 LE) | payload | checksum (uint16 LE)

The checksum runs over the whole message before it, preamble included, starting from 0xFFFF. It
is Weiss's table CRC: the MSB-first CRC-CCITT table (polynomial 0x1021) indexed by the low byte,
`crc = TABLE[(crc ^ byte) & 0xFF] ^ (crc >> 8)`. This mixes the MSB-first table with an LSB-first
update, so it is *not* `binascii.crc_hqx` (which gives 0x50D4 over the preamble where the WSG
gives 0x50F5, the constant in Weiss's reference driver `msg.c`). A message followed by its own
little-endian checksum has checksum 0. A reply payload starts with a uint16 LE status code.
"""

from __future__ import annotations

import dataclasses
import enum
import struct

PREAMBLE = b"\xaa\xaa\xaa"
HEADER_SIZE = len(PREAMBLE) + 3  # preamble, command id, payload size
CHECKSUM_SIZE = 2
CHECKSUM_START = 0xFFFF
CHECKSUM_OF_PREAMBLE = 0x50F5  # Weiss reference driver, msg.c
MAX_PAYLOAD_SIZE = 1024  # far above any reply of the commands used here; guards against bad lengths


def _checksum_table(polynomial: int = 0x1021) -> tuple[int, ...]:
    """The MSB-first CRC-16 table of `polynomial` (entry 1 is the polynomial itself)."""
    table = []
    for index in range(256):
        value = index << 8
        for _ in range(8):
            value = (value << 1) ^ polynomial if value & 0x8000 else value << 1
        table.append(value & 0xFFFF)
    return tuple(table)


_CHECKSUM_TABLE = _checksum_table()


def checksum(data: bytes, start: int = CHECKSUM_START) -> int:
    """The WSG's 16-bit checksum of `data`, continuing from `start` (0xFFFF for a new message)."""
    value = start
    for byte in data:
        value = _CHECKSUM_TABLE[(value ^ byte) & 0xFF] ^ (value >> 8)
    return value


class CommandId(enum.IntEnum):
    """Command ids of the WSG command set used or emulated here."""

    LOOP = 0x06
    DISCONNECT_ANNOUNCEMENT = 0x07
    HOMING = 0x20
    MOVE = 0x21  # "pre-position fingers"
    STOP = 0x22
    FAST_STOP = 0x23
    ACKNOWLEDGE_FAULT = 0x24
    GRASP = 0x25
    RELEASE = 0x26
    SET_ACCELERATION = 0x30
    GET_ACCELERATION = 0x31
    SET_FORCE_LIMIT = 0x32
    GET_FORCE_LIMIT = 0x33
    TARE_FORCE_SENSOR = 0x38
    GET_SYSTEM_STATE = 0x40
    GET_GRASPING_STATE = 0x41
    GET_OPENING_WIDTH = 0x43
    GET_SPEED = 0x44
    GET_FORCE = 0x45
    GET_TEMPERATURE = 0x46
    GET_SYSTEM_INFO = 0x50
    GET_SYSTEM_LIMITS = 0x53


class GripperStatus(enum.IntEnum):
    """WSG status codes; every reply payload starts with one (uint16 LE)."""

    E_SUCCESS = 0
    E_NOT_AVAILABLE = 1
    E_NO_SENSOR = 2
    E_NOT_INITIALIZED = 3
    E_ALREADY_RUNNING = 4
    E_FEATURE_NOT_SUPPORTED = 5
    E_INCONSISTENT_DATA = 6
    E_TIMEOUT = 7
    E_READ_ERROR = 8
    E_WRITE_ERROR = 9
    E_INSUFFICIENT_RESOURCES = 10
    E_CHECKSUM_ERROR = 11
    E_NO_PARAM_EXPECTED = 12
    E_NOT_ENOUGH_PARAMS = 13
    E_CMD_UNKNOWN = 14
    E_CMD_FORMAT_ERROR = 15
    E_ACCESS_DENIED = 16
    E_ALREADY_OPEN = 17
    E_CMD_FAILED = 18
    E_CMD_ABORTED = 19
    E_INVALID_HANDLE = 20
    E_NOT_FOUND = 21
    E_NOT_OPEN = 22
    E_IO_ERROR = 23
    E_INVALID_PARAMETER = 24
    E_INDEX_OUT_OF_BOUNDS = 25
    E_CMD_PENDING = 26
    E_OVERRUN = 27
    E_RANGE_ERROR = 28
    E_AXIS_BLOCKED = 29
    E_FILE_EXISTS = 30


STATUS_DESCRIPTIONS: dict[GripperStatus, str] = {
    GripperStatus.E_SUCCESS: "no error",
    GripperStatus.E_NOT_AVAILABLE: "device, service or data is not available",
    GripperStatus.E_NO_SENSOR: "no sensor connected",
    GripperStatus.E_NOT_INITIALIZED: "the device is not initialized (home it first)",
    GripperStatus.E_ALREADY_RUNNING: "service is already running",
    GripperStatus.E_FEATURE_NOT_SUPPORTED: "the requested feature is not supported",
    GripperStatus.E_INCONSISTENT_DATA: "one or more dependent parameters mismatch",
    GripperStatus.E_TIMEOUT: "timeout error",
    GripperStatus.E_READ_ERROR: "error while reading from a device",
    GripperStatus.E_WRITE_ERROR: "error while writing to a device",
    GripperStatus.E_INSUFFICIENT_RESOURCES: "no memory available",
    GripperStatus.E_CHECKSUM_ERROR: "checksum error",
    GripperStatus.E_NO_PARAM_EXPECTED: "no parameters expected",
    GripperStatus.E_NOT_ENOUGH_PARAMS: "not enough parameters",
    GripperStatus.E_CMD_UNKNOWN: "unknown command",
    GripperStatus.E_CMD_FORMAT_ERROR: "command format error",
    GripperStatus.E_ACCESS_DENIED: "access denied",
    GripperStatus.E_ALREADY_OPEN: "the interface is already open",
    GripperStatus.E_CMD_FAILED: "command failed",
    GripperStatus.E_CMD_ABORTED: "command aborted",
    GripperStatus.E_INVALID_HANDLE: "invalid handle",
    GripperStatus.E_NOT_FOUND: "device not found",
    GripperStatus.E_NOT_OPEN: "device not open",
    GripperStatus.E_IO_ERROR: "general I/O error",
    GripperStatus.E_INVALID_PARAMETER: "invalid parameter",
    GripperStatus.E_INDEX_OUT_OF_BOUNDS: "index out of bounds",
    GripperStatus.E_CMD_PENDING: "command execution needs more time",
    GripperStatus.E_OVERRUN: "data overrun",
    GripperStatus.E_RANGE_ERROR: "value out of range",
    GripperStatus.E_AXIS_BLOCKED: "axis is blocked",
    GripperStatus.E_FILE_EXISTS: "file already exists",
}


class GraspingState(enum.IntEnum):
    """The gripper's grasping state (reply of GET_GRASPING_STATE)."""

    IDLE = 0
    GRASPING = 1
    NO_PART_FOUND = 2
    PART_LOST = 3
    HOLDING = 4
    RELEASING = 5
    POSITIONING = 6
    ERROR = 7


def status_name(code: int) -> str:
    """A readable name for a status code, e.g. `"E_CMD_FAILED (command failed)"`."""
    try:
        status = GripperStatus(code)
    except ValueError:
        return f"unknown status {code}"
    return f"{status.name} ({STATUS_DESCRIPTIONS[status]})"


def command_name(command_id: int) -> str:
    """A readable name for a command id, e.g. `"GRASP (0x25)"`."""
    try:
        return f"{CommandId(command_id).name} (0x{command_id:02X})"
    except ValueError:
        return f"command 0x{command_id:02X}"


class GripperError(Exception):
    """Base class of every error raised while talking to the gripper."""


class GripperProtocolError(GripperError):
    """A frame or reply that breaks the protocol: bad length, missing status, unexpected size."""


class GripperChecksumError(GripperProtocolError):
    """A frame whose checksum does not match its content; nothing in it was used."""


class GripperTimeoutError(GripperError, TimeoutError):
    """No complete reply arrived in time."""


class GripperDisconnectedError(GripperError, ConnectionError):
    """The serial port or TCP connection is closed or broke."""


class GripperStatusError(GripperError):
    """The gripper answered a command with an error status.

    Attributes:
        command_id: the command that failed.
        status: the status code (a `GripperStatus` when known).
        status_name: the code's readable name, e.g. "E_CMD_FAILED (command failed)".
    """

    def __init__(self, command_id: int, status: int, hint: str = ""):
        self.command_id = command_id
        try:
            self.status: int = GripperStatus(status)
        except ValueError:
            self.status = status
        self.status_name = status_name(status)
        message = f"WSG {command_name(command_id)} failed with status {self.status_name}"
        super().__init__(f"{message}: {hint}" if hint else message)


@dataclasses.dataclass(frozen=True)
class Frame:
    """One protocol message: a command id and its payload (status code first in replies)."""

    command_id: int
    payload: bytes = b""

    def encode(self) -> bytes:
        """The message as sent on the wire: preamble, header, payload and checksum."""
        return encode_frame(self.command_id, self.payload)

    def status(self) -> int:
        """The reply's status code; raises GripperProtocolError for a payload shorter than 2 bytes."""
        if len(self.payload) < 2:
            raise GripperProtocolError(
                f"reply to {command_name(self.command_id)} has {len(self.payload)} payload bytes, "
                "too few for a status code")
        return int.from_bytes(self.payload[:2], "little")

    def parameters(self) -> bytes:
        """The reply's payload after the status code."""
        return self.payload[2:]


def encode_frame(command_id: int, payload: bytes = b"") -> bytes:
    """Frame `payload` as a message with id `command_id` (0-255, but not the preamble byte 0xAA)."""
    if not 0 <= command_id <= 0xFF or command_id == PREAMBLE[0]:
        raise ValueError(f"command id must be 0x00-0xFF and not 0xAA, got {command_id!r}")
    if len(payload) > 0xFFFF:
        raise ValueError(f"payload is {len(payload)} bytes, the protocol allows at most 65535")
    message = PREAMBLE + bytes([command_id]) + len(payload).to_bytes(2, "little") + bytes(payload)
    return message + checksum(message).to_bytes(2, "little")


def pack_floats(*values: float) -> bytes:
    """Little-endian IEEE-754 float32 values, the protocol's encoding of mm, mm/s and N."""
    return struct.pack(f"<{len(values)}f", *values)


def unpack_float(data: bytes) -> float:
    """The one little-endian float32 in `data` (exactly 4 bytes)."""
    if len(data) != 4:
        raise GripperProtocolError(f"expected a 4-byte float, got {len(data)} bytes")
    return struct.unpack("<f", data)[0]


class FrameParser:
    """Incremental parser: feed it bytes as they arrive, take out complete, verified frames.

    Bytes before a preamble are skipped (counted in `skipped_bytes`). A run of more than three
    0xAA bytes is read as garbage followed by the preamble, so 0xAA is never a command id. A frame
    with a bad checksum or a payload size above `max_payload_size` raises; the parser then drops the
    offending preamble byte so that the next call resynchronises on the bytes after it.
    """

    def __init__(self, max_payload_size: int = MAX_PAYLOAD_SIZE):
        self.max_payload_size = max_payload_size
        self.skipped_bytes = 0
        self._buffer = bytearray()

    def feed(self, data: bytes) -> None:
        """Append received bytes."""
        self._buffer.extend(data)

    def clear(self) -> None:
        """Forget buffered bytes, e.g. before a new command whose reply must not mix with old ones."""
        self._buffer.clear()

    @property
    def buffered(self) -> int:
        """Number of bytes received but not yet parsed."""
        return len(self._buffer)

    def next_frame(self) -> Frame | None:
        """The next complete frame, or None until more bytes arrive.

        Raises:
            GripperChecksumError: the frame at the head of the buffer fails its checksum.
            GripperProtocolError: its payload size exceeds `max_payload_size`.
        """
        self._skip_to_preamble()
        if len(self._buffer) < HEADER_SIZE:
            return None
        command_id = self._buffer[3]
        payload_size = int.from_bytes(self._buffer[4:6], "little")
        if payload_size > self.max_payload_size:
            self._skip(1)
            raise GripperProtocolError(
                f"frame {command_name(command_id)} announces {payload_size} payload bytes, more than "
                f"the {self.max_payload_size} accepted: corrupted header")
        frame_size = HEADER_SIZE + payload_size + CHECKSUM_SIZE
        if len(self._buffer) < frame_size:
            return None
        message = bytes(self._buffer[:frame_size])
        if checksum(message) != 0:  # a message followed by its own checksum sums to 0
            self._skip(1)
            received = int.from_bytes(message[-2:], "little")
            raise GripperChecksumError(
                f"frame {command_name(command_id)} with {payload_size} payload bytes has checksum "
                f"0x{received:04X}, expected 0x{checksum(message[:-2]):04X}: corrupted in transit")
        del self._buffer[:frame_size]
        return Frame(command_id, message[HEADER_SIZE:-CHECKSUM_SIZE])

    def _skip_to_preamble(self) -> None:
        start = self._buffer.find(PREAMBLE)
        if start < 0:
            # Keep a trailing partial preamble (up to two 0xAA bytes) for the next feed.
            keep = len(self._buffer) - len(self._buffer.rstrip(PREAMBLE[:1]))
            self._skip(len(self._buffer) - min(keep, len(PREAMBLE) - 1))
            return
        while start + len(PREAMBLE) < len(self._buffer) and self._buffer[start + len(PREAMBLE)] == PREAMBLE[0]:
            start += 1
        self._skip(start)

    def _skip(self, count: int) -> None:
        self.skipped_bytes += count
        del self._buffer[:count]
