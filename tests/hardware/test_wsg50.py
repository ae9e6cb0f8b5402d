"""WSG-50 protocol framing, the client against the emulator over a pty and TCP, and injected faults."""

import binascii
import math
import socket
import struct
import sys
import time
import types

import hypothesis.strategies as st
import pytest
from hypothesis import given, settings

from tactojax.hardware._wsg50 import WSG50
from tactojax.hardware._wsg50_emulator import GARBAGE, EmulatorFault, WSG50Emulator
from tactojax.hardware._wsg50_protocol import (
    CHECKSUM_OF_PREAMBLE,
    PREAMBLE,
    CommandId,
    Frame,
    FrameParser,
    GraspingState,
    GripperChecksumError,
    GripperDisconnectedError,
    GripperProtocolError,
    GripperStatus,
    GripperStatusError,
    GripperTimeoutError,
    checksum,
    encode_frame,
    pack_floats,
    status_name,
)

TIMEOUT_S = 0.2
TRANSPORTS = ["tcp"] if sys.platform == "win32" else ["pty", "tcp"]
command_ids = st.integers(0, 0xFF).filter(lambda command_id: command_id != 0xAA)


def reference_checksum(data: bytes, value: int = 0xFFFF) -> int:
    """Weiss's table CRC, built from an independent table: entry i of the MSB-first CRC-CCITT table
    (polynomial 0x1021) is the CRC of the single byte i from 0, which is `binascii.crc_hqx`."""
    for byte in data:
        value = binascii.crc_hqx(bytes([(value ^ byte) & 0xFF]), 0) ^ (value >> 8)
    return value


def reply_frame(command_id: int, status: GripperStatus, parameters: bytes = b"") -> bytes:
    return encode_frame(command_id, struct.pack("<H", status) + parameters)


def parse_all(stream: bytes, chunk_size: int = 1) -> list[Frame]:
    """Feed `stream` in chunks and collect the frames; errors propagate."""
    parser, frames = FrameParser(), []
    for start in range(0, len(stream), chunk_size):
        parser.feed(stream[start:start + chunk_size])
        while (frame := parser.next_frame()) is not None:
            frames.append(frame)
    return frames


# Checksum and framing.


def test_checksum_of_preamble_is_the_weiss_constant_and_not_plain_crc_ccitt():
    # 0x50F5 is hard-coded as "checksum over preamble" in Weiss's reference driver (msg.c).
    assert checksum(PREAMBLE) == CHECKSUM_OF_PREAMBLE == 0x50F5
    assert binascii.crc_hqx(PREAMBLE, 0xFFFF) != 0x50F5  # the textbook CRC-CCITT would be wrong


@settings(max_examples=30, deadline=None)
@given(data=st.binary(max_size=64), start=st.integers(0, 0xFFFF))
def test_checksum_matches_independent_reference(data, start):
    assert checksum(data, start) == reference_checksum(data, start)


def test_homing_frame_layout():
    frame = encode_frame(CommandId.HOMING, b"\x00")
    body = b"\xaa\xaa\xaa\x20\x01\x00\x00"  # preamble, id 0x20, size 1 (LE), direction 0
    assert frame == body + reference_checksum(body).to_bytes(2, "little")
    assert checksum(frame) == 0  # a message followed by its own checksum sums to 0


@settings(max_examples=25, deadline=None)
@given(command_id=command_ids, payload=st.binary(max_size=80), chunk_size=st.integers(1, 9),
       garbage=st.binary(max_size=12).map(lambda data: data.replace(b"\xaa", b"\x55")))
def test_frames_survive_garbage_and_split_reads(command_id, payload, chunk_size, garbage):
    stream = garbage + encode_frame(command_id, payload) + encode_frame(0x43, payload[::-1])
    assert parse_all(stream, chunk_size) == [Frame(command_id, payload), Frame(0x43, payload[::-1])]


def test_parser_skips_partial_preambles_and_a_preamble_run():
    frame = reply_frame(CommandId.GET_OPENING_WIDTH, GripperStatus.E_SUCCESS, pack_floats(42.5))
    # GARBAGE holds 0xAA and 0xAA 0xAA and ends in 0xAA, so the frame follows a run of four 0xAA.
    assert GARBAGE.endswith(b"\xaa") and PREAMBLE not in GARBAGE
    for chunk_size in (1, 4, 100):
        (parsed,) = parse_all(GARBAGE + frame, chunk_size)
        assert parsed.status() == GripperStatus.E_SUCCESS
        assert struct.unpack("<f", parsed.parameters()) == (42.5,)


def test_parser_waits_for_the_whole_frame():
    frame = reply_frame(CommandId.GET_FORCE, GripperStatus.E_SUCCESS, pack_floats(12.0))
    parser = FrameParser()
    for byte in frame[:-1]:
        parser.feed(bytes([byte]))
        assert parser.next_frame() is None
    parser.feed(frame[-1:])
    assert parser.next_frame() == Frame(CommandId.GET_FORCE, frame[6:-2])


def test_parser_rejects_bad_checksum_then_resynchronises():
    bad = bytearray(reply_frame(CommandId.GET_OPENING_WIDTH, GripperStatus.E_SUCCESS, pack_floats(30.0)))
    bad[8] ^= 0x10
    good = reply_frame(CommandId.GET_OPENING_WIDTH, GripperStatus.E_SUCCESS, pack_floats(31.0))
    parser = FrameParser()
    parser.feed(bytes(bad) + good)
    with pytest.raises(GripperChecksumError, match="checksum"):
        parser.next_frame()
    assert parser.next_frame() == Frame(CommandId.GET_OPENING_WIDTH, good[6:-2])


def test_parser_rejects_oversized_length_then_resynchronises():
    good = reply_frame(CommandId.STOP, GripperStatus.E_SUCCESS)
    parser = FrameParser(max_payload_size=64)
    parser.feed(PREAMBLE + b"\x43\xff\xff" + good)
    with pytest.raises(GripperProtocolError, match="65535 payload bytes") as error:
        parser.next_frame()
    assert not isinstance(error.value, GripperChecksumError)
    assert parser.next_frame() == Frame(CommandId.STOP, good[6:-2])


def test_no_single_bit_flip_of_an_opening_reply_yields_a_frame():
    frame = reply_frame(CommandId.GET_OPENING_WIDTH, GripperStatus.E_SUCCESS, pack_floats(42.0))
    for bit in range(8 * len(frame)):
        corrupted = bytearray(frame)
        corrupted[bit // 8] ^= 1 << (bit % 8)
        parser = FrameParser()
        parser.feed(bytes(corrupted))
        frames = []
        try:
            while (parsed := parser.next_frame()) is not None:
                frames.append(parsed)
        except GripperProtocolError:
            pass
        assert frames == [], f"bit {bit} flipped, yet a frame was accepted"


def test_encode_rejects_invalid_command_ids():
    for command_id in (-1, 0x100, 0xAA):
        with pytest.raises(ValueError, match="command id"):
            encode_frame(command_id)


def test_status_table_and_status_error():
    assert [status.value for status in GripperStatus] == list(range(31))
    assert GripperStatus.E_CMD_PENDING == 26 and GripperStatus.E_CMD_FAILED == 18
    assert status_name(26).startswith("E_CMD_PENDING") and "unknown" in status_name(99)
    error = GripperStatusError(CommandId.GRASP, 18, "no part")
    assert error.status is GripperStatus.E_CMD_FAILED and error.command_id == 0x25
    assert "GRASP (0x25)" in str(error) and "E_CMD_FAILED" in str(error) and "no part" in str(error)
    assert GripperStatusError(CommandId.MOVE, 77).status == 77


# The client against the emulator.


@pytest.fixture(params=TRANSPORTS)
def transport(request):
    return request.param


@pytest.fixture(autouse=True)
def no_pause_after_socket_close(monkeypatch):
    """pyserial sleeps 0.3 s after closing a socket:// port, to let real devices accept a quick
    reconnect; the emulator needs no such pause, and the file must stay fast."""
    from serial.urlhandler import protocol_socket

    monkeypatch.setattr(protocol_socket, "time", types.SimpleNamespace(sleep=lambda seconds: None))


def serve(emulator: WSG50Emulator, transport: str) -> str:
    return emulator.serve_pty() if transport == "pty" else emulator.serve_tcp()


@pytest.fixture
def emulator():
    with WSG50Emulator() as emulator:
        yield emulator


@pytest.fixture
def gripper(emulator, transport):
    with WSG50(serve(emulator, transport), timeout_s=TIMEOUT_S) as gripper:
        gripper.home()
        yield gripper


def test_home_move_grasp_read_release(emulator, transport):
    with WSG50(serve(emulator, transport), timeout_s=TIMEOUT_S) as gripper:
        with pytest.raises(GripperStatusError, match="E_NOT_INITIALIZED") as error:
            gripper.move(80.0, 100.0)
        assert error.value.status is GripperStatus.E_NOT_INITIALIZED
        gripper.home()
        assert gripper.opening_mm() == emulator.stroke_mm
        gripper.move(80.0, 100.0)
        assert gripper.opening_mm() == 80.0

        emulator.object_width_mm = 40.0
        gripper.grasp(42.0, 50.0, force_n=20.0)
        assert gripper.opening_mm() == 40.0
        assert gripper.force_n() == 20.0
        assert gripper.grasping_state() is GraspingState.HOLDING
        received = emulator.commands_received
        assert received.index(CommandId.SET_FORCE_LIMIT) < received.index(CommandId.GRASP)

        gripper.release(90.0, 100.0)
        assert (gripper.opening_mm(), gripper.force_n()) == (90.0, 0.0)
        assert gripper.grasping_state() is GraspingState.IDLE
    # Every motion was acknowledged with E_CMD_PENDING before its final reply.
    for command_id in (CommandId.HOMING, CommandId.MOVE, CommandId.GRASP, CommandId.RELEASE):
        statuses = [status for sent_id, status in emulator.replies_sent if sent_id == command_id]
        assert statuses[-2:] == [GripperStatus.E_CMD_PENDING, GripperStatus.E_SUCCESS]
    assert emulator.commands_received[-1] == CommandId.DISCONNECT_ANNOUNCEMENT


def test_grasp_without_object_fails_with_no_part(gripper, emulator):
    emulator.object_width_mm = None
    with pytest.raises(GripperStatusError, match="no part") as error:
        gripper.grasp(42.0, 50.0)
    assert error.value.status is GripperStatus.E_CMD_FAILED
    assert gripper.grasping_state() is GraspingState.NO_PART_FOUND
    assert gripper.opening_mm() == 42.0 - emulator.clamping_travel_mm  # fell through the clamping travel


def test_move_blocked_by_object(gripper, emulator):
    emulator.object_width_mm = 60.0
    with pytest.raises(GripperStatusError) as error:
        gripper.move(20.0, 100.0)
    assert error.value.status is GripperStatus.E_AXIS_BLOCKED
    assert gripper.opening_mm() == 60.0


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_motion_returns_only_after_the_final_reply(transport):
    with WSG50Emulator(time_scale=1.0, width_mm=100.0, require_homing=False) as emulator:
        with WSG50(serve(emulator, transport), timeout_s=TIMEOUT_S) as gripper:
            gripper.move(92.0, 100.0)  # 80 ms of emulated motion, longer than nothing
            assert emulator.width_mm == 92.0  # finished, not in between
            assert emulator.replies_sent[-2:] == [(CommandId.MOVE, GripperStatus.E_CMD_PENDING),
                                                  (CommandId.MOVE, GripperStatus.E_SUCCESS)]


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_stop_aborts_a_motion(transport):
    with WSG50Emulator(time_scale=1.0, width_mm=110.0, require_homing=False) as emulator:
        with WSG50(serve(emulator, transport), timeout_s=TIMEOUT_S) as gripper:
            gripper.move(10.0, 20.0, wait=False)  # would take 5 s
            time.sleep(0.05)
            gripper.stop()  # skips the MOVE's late E_CMD_ABORTED reply
            stopped_mm = gripper.opening_mm()
            assert 10.0 < stopped_mm < 110.0
            time.sleep(0.05)
            assert gripper.opening_mm() == stopped_mm
    assert (CommandId.MOVE, GripperStatus.E_CMD_ABORTED) in emulator.replies_sent


def test_fast_stop_needs_acknowledgement(gripper):
    gripper.fast_stop()
    with pytest.raises(GripperStatusError, match="E_ACCESS_DENIED"):
        gripper.move(50.0, 100.0)
    gripper.acknowledge_fault()
    gripper.move(50.0, 100.0)
    assert gripper.opening_mm() == 50.0


@pytest.mark.parametrize("call, message", [
    (lambda gripper: gripper.move(-1.0, 50.0), "width_mm"),
    (lambda gripper: gripper.move(110.5, 50.0), "width_mm"),
    (lambda gripper: gripper.move(math.nan, 50.0), "width_mm"),
    (lambda gripper: gripper.grasp(40.0, 0.0), "speed_mm_s"),
    (lambda gripper: gripper.release(60.0, 421.0), "speed_mm_s"),
    (lambda gripper: gripper.grasp(40.0, 50.0, force_n=81.0), "force_n"),
    (lambda gripper: gripper.set_force_limit(0.0), "force_n"),
    (lambda gripper: gripper.home(direction="up"), "direction"),
])
def test_invalid_arguments_are_rejected_before_sending(gripper, emulator, call, message):
    sent_before = list(emulator.commands_received)
    with pytest.raises(ValueError, match=message):
        call(gripper)
    assert emulator.commands_received == sent_before


def test_error_status_is_raised_with_its_name(gripper, emulator):
    emulator.inject_error_status(GripperStatus.E_IO_ERROR)
    with pytest.raises(GripperStatusError, match=r"GET_OPENING_WIDTH \(0x43\).*E_IO_ERROR") as error:
        gripper.opening_mm()
    assert error.value.status is GripperStatus.E_IO_ERROR
    assert gripper.opening_mm() == emulator.stroke_mm  # the next command works


def test_corrupted_replies_never_give_an_opening(gripper, emulator):
    for fault in (EmulatorFault.CORRUPT_CHECKSUM, EmulatorFault.CORRUPT_PAYLOAD):
        emulator.inject_fault(fault)
        with pytest.raises(GripperChecksumError):
            gripper.opening_mm()
        assert gripper.opening_mm() == emulator.stroke_mm  # recovers on the next command
    emulator.inject_fault(EmulatorFault.CORRUPT_CHECKSUM)  # the E_CMD_PENDING acknowledgement
    with pytest.raises(GripperChecksumError):
        gripper.move(50.0, 100.0)


def test_dropped_reply_times_out(gripper, emulator):
    emulator.inject_fault(EmulatorFault.DROP_REPLY)
    with pytest.raises(GripperTimeoutError, match="GET_FORCE"):
        gripper.force_n()
    assert gripper.force_n() == 0.0


@pytest.mark.parametrize("fault", [EmulatorFault.GARBAGE_BEFORE_REPLY, EmulatorFault.SPLIT_REPLY])
def test_garbage_and_split_replies_are_read_correctly(gripper, emulator, fault):
    gripper.move(33.0, 100.0)
    emulator.inject_fault(fault)
    assert gripper.opening_mm() == 33.0
    emulator.inject_fault(fault, count=2)
    gripper.move(44.0, 100.0)  # both its E_CMD_PENDING and its final reply are affected
    assert gripper.opening_mm() == 44.0


def test_disconnect_mid_reply(emulator, transport):
    url = serve(emulator, transport)
    gripper = WSG50(url, timeout_s=TIMEOUT_S)
    emulator.inject_fault(EmulatorFault.DISCONNECT_MID_REPLY)
    with pytest.raises(GripperDisconnectedError):
        gripper.opening_mm()
    with pytest.raises(GripperDisconnectedError):
        gripper.opening_mm()
    gripper.close()  # the disconnect announcement fails quietly
    assert not gripper.is_open
    with pytest.raises(GripperDisconnectedError, match="closed"):
        gripper.opening_mm()
    if transport == "tcp":  # the emulated gripper accepts a new connection
        with WSG50(url, timeout_s=TIMEOUT_S) as reconnected:
            assert reconnected.opening_mm() == 55.0


def test_unreachable_gripper_raises_disconnected():
    with socket.create_server(("127.0.0.1", 0)) as listener:
        port = listener.getsockname()[1]
    with pytest.raises(GripperDisconnectedError, match="cannot open"):
        WSG50(f"socket://127.0.0.1:{port}", timeout_s=TIMEOUT_S)
