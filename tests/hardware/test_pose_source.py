"""Pose logs (CSV/JSON), interpolation against scipy's Slerp, staleness, and UDP over loopback."""

import json
import socket
import time

import jaxlie
import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from tactojax.hardware._pose_source import (
    PACKET_SIZE,
    PoseLog,
    PoseSample,
    StaleDataError,
    UdpPoseReceiver,
    decode_pose_packet,
    encode_pose_packet,
    read_pose_log,
    send_pose,
    write_pose_log,
)


def _random_log(count=12, seed=0):
    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.uniform(0.005, 0.02, count)) + 100.0
    xyzw = Rotation.random(count, random_state=seed).as_quat()
    wxyz = np.roll(xyzw, 1, axis=1) * rng.choice([-1.0, 1.0], (count, 1))  # either sign of q
    xyz = rng.normal(0.0, 200.0, (count, 3))
    return PoseLog(times, np.concatenate([wxyz, xyz], axis=1))


@pytest.mark.parametrize("suffix", [".csv", ".json"])
def test_pose_log_round_trip(tmp_path, suffix):
    log = _random_log()
    read = read_pose_log(write_pose_log(tmp_path / f"poses{suffix}", log))
    np.testing.assert_array_equal(read.timestamps_s, log.timestamps_s)
    np.testing.assert_allclose(read.wxyz_xyz, log.wxyz_xyz, rtol=0, atol=1e-15)


def test_csv_with_slightly_unnormalised_quaternions_is_normalised(tmp_path):
    path = tmp_path / "poses.csv"
    path.write_text("timestamp_s, qw, qx, qy, qz, x_mm, y_mm, z_mm\n"
                    "0.0,1.0005,0,0,0,1,2,3\n\n"
                    "0.1,0,0,0,0.9995,4,5,6\n")
    log = read_pose_log(path)
    np.testing.assert_allclose(log.wxyz_xyz, [[1, 0, 0, 0, 1, 2, 3], [0, 0, 0, 1, 4, 5, 6]])


@pytest.mark.parametrize(("text", "message"), [
    ("t,qw,qx,qy,qz,x,y,z\n0,1,0,0,0,0,0,0\n", "line 1: header must be"),
    ("", "empty file"),
    ("timestamp_s,qw,qx,qy,qz,x_mm,y_mm,z_mm\n", "no samples"),
    ("timestamp_s,qw,qx,qy,qz,x_mm,y_mm,z_mm\n0,1,0,0,0,0,0,0\n0.1,1,0,0,0,0,0\n", "line 3: expected 8 fields"),
    ("timestamp_s,qw,qx,qy,qz,x_mm,y_mm,z_mm\n0,1,0,0,0,0,0,0\n0.1,1,0,0,0,abc,0,0\n", "line 3: could not convert"),
    ("timestamp_s,qw,qx,qy,qz,x_mm,y_mm,z_mm\n0,1,0,0,0,0,0,0\n0.1,1,0,0,0,0,0,0\n0.1,1,0,0,0,0,0,0\n",
     "line 4: timestamp 0.1 s is not after"),
    ("timestamp_s,qw,qx,qy,qz,x_mm,y_mm,z_mm\n0,1,0,0,0,0,0,0\n0.1,1,0,0,0.1,0,0,0\n", "line 3: quaternion norm 1.004"),
    ("timestamp_s,qw,qx,qy,qz,x_mm,y_mm,z_mm\n0,1,0,0,0,nan,0,0\n", "line 2: values must be finite"),
])
def test_malformed_csv_names_the_line(tmp_path, text, message):
    path = tmp_path / "poses.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        read_pose_log(path)


@pytest.mark.parametrize(("entries", "message"), [
    ({"timestamp_s": 0.0}, "expected a non-empty list"),
    ([{"timestamp_s": 0.0, "T_world_gripper": [1, 0, 0, 0, 0, 0, 0]}, {"timestamp_s": 1.0}],
     "entry 1: expected an object"),
    ([{"timestamp_s": 0.0, "T_world_gripper": [1, 0, 0, 0, 0, 0]}], "entry 0: T_world_gripper must be 7"),
    ([{"timestamp_s": 0.0, "T_world_gripper": [1, 0, 0, 0, 0, 0, 0]},
      {"timestamp_s": 1.0, "T_world_gripper": [2, 0, 0, 0, 0, 0, 0]}], "entry 1: quaternion norm 2"),
])
def test_malformed_json_names_the_entry(tmp_path, entries, message):
    path = tmp_path / "poses.json"
    path.write_text(json.dumps(entries))
    with pytest.raises(ValueError, match=message):
        read_pose_log(path)


def test_interpolation_matches_scipy_slerp():
    log = _random_log(seed=1)
    rng = np.random.default_rng(2)
    queries = rng.uniform(log.timestamps_s[0], log.timestamps_s[-1], 50)
    reference = Slerp(log.timestamps_s, Rotation.from_quat(np.roll(log.wxyz_xyz[:, :4], -1, axis=1)))(queries)

    samples = [log.pose_at(t, max_skew_s=0.02) for t in queries]

    poses = np.stack([np.asarray(sample.T_world_gripper.wxyz_xyz) for sample in samples])
    np.testing.assert_allclose(np.linalg.norm(poses[:, :4], axis=1), 1.0, atol=1e-12)
    rotations = Rotation.from_quat(np.roll(poses[:, :4], -1, axis=1)).as_matrix()
    translations = poses[:, 4:]
    np.testing.assert_allclose(rotations, reference.as_matrix(), atol=1e-9)
    for axis in range(3):
        np.testing.assert_allclose(translations[:, axis], np.interp(queries, log.timestamps_s,
                                                                    log.wxyz_xyz[:, 4 + axis]), atol=1e-9)
    np.testing.assert_array_equal([sample.timestamp_s for sample in samples], queries)


def test_nearest_sample_and_no_extrapolation():
    log = PoseLog([0.0, 1.0], [[1, 0, 0, 0, 0, 0, 0], [0, 1, 0, 0, 10, 0, 0]])
    nearest = log.pose_at(0.7, max_skew_s=0.5, interpolate=False)
    assert nearest.timestamp_s == 1.0
    np.testing.assert_array_equal(nearest.T_world_gripper.wxyz_xyz, log.wxyz_xyz[1])
    after_end = log.pose_at(1.05, max_skew_s=0.1)
    assert after_end.timestamp_s == 1.0
    np.testing.assert_array_equal(after_end.T_world_gripper.wxyz_xyz, log.wxyz_xyz[1])


def test_stale_lookups_say_by_how_much():
    log = PoseLog([0.0, 1.0], [[1, 0, 0, 0, 0, 0, 0], [1, 0, 0, 0, 10, 0, 0]])
    with pytest.raises(StaleDataError, match="robot pose is stale") as error:
        log.pose_at(1.25, max_skew_s=0.1)
    assert error.value.stream == "robot pose"
    assert error.value.skew_s == pytest.approx(0.25)
    with pytest.raises(StaleDataError) as error:
        log.pose_at(0.5, max_skew_s=0.1)  # inside the log, but in a 1 s gap
    assert error.value.skew_s == pytest.approx(0.5)
    assert log.pose_at(0.95, max_skew_s=0.1).T_world_gripper.wxyz_xyz[4] == pytest.approx(9.5)


def test_pose_packets_round_trip_and_reject_garbage():
    pose = np.array([0.5, 0.5, 0.5, 0.5, 1.0, -2.0, 3.5])
    packet = encode_pose_packet(12.25, pose)
    assert len(packet) == PACKET_SIZE == 68
    timestamp_s, decoded = decode_pose_packet(packet)
    assert timestamp_s == 12.25
    np.testing.assert_array_equal(decoded, pose)
    with pytest.raises(ValueError, match="67 bytes"):
        decode_pose_packet(packet[:-1])
    with pytest.raises(ValueError, match="starts with"):
        decode_pose_packet(b"XXXX" + packet[4:])


class _ManualClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def _wait_for(condition, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out waiting for UDP packets"
        time.sleep(0.005)


def test_udp_receiver_over_loopback():
    log = _random_log(count=6, seed=3)
    clock = _ManualClock()
    with UdpPoseReceiver("127.0.0.1", 0, capacity=4, clock=clock) as receiver, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        for i in range(len(log)):
            send_pose(sender, receiver.address, log.pose_at(log.timestamps_s[i], max_skew_s=0.0))
        sender.sendto(b"short", receiver.address)
        sender.sendto(b"XXXX" + encode_pose_packet(200.0, log.wxyz_xyz[0])[4:], receiver.address)
        sender.sendto(encode_pose_packet(200.0, [np.nan, 0, 0, 0, 0, 0, 0]), receiver.address)
        sender.sendto(encode_pose_packet(200.0, [2, 0, 0, 0, 0, 0, 0]), receiver.address)
        sender.sendto(encode_pose_packet(200.0, log.wxyz_xyz[0]) + b"x", receiver.address)
        send_pose(sender, receiver.address, log.pose_at(log.timestamps_s[2], max_skew_s=0.0))  # old
        _wait_for(lambda: receiver.received_packets == len(log) + 6)

        assert receiver.malformed_packets == 5
        assert receiver.out_of_order_packets == 1
        newest = receiver.latest(max_age_s=1.0)
        assert newest.timestamp_s == log.timestamps_s[-1]
        np.testing.assert_allclose(newest.T_world_gripper.wxyz_xyz, log.wxyz_xyz[-1], atol=1e-15)
        # The ring keeps the 4 newest samples; lookups between them interpolate as the log does.
        middle = 0.5 * (log.timestamps_s[3] + log.timestamps_s[4])
        np.testing.assert_allclose(receiver.pose_at(middle, max_skew_s=0.02).T_world_gripper.wxyz_xyz,
                                   log.pose_at(middle, max_skew_s=0.02).T_world_gripper.wxyz_xyz, atol=1e-12)
        with pytest.raises(StaleDataError):
            receiver.pose_at(log.timestamps_s[1], max_skew_s=1e-4)  # dropped from the ring
        clock.now = 3.0
        with pytest.raises(StaleDataError, match="newest packet arrived too long ago") as error:
            receiver.latest(max_age_s=1.0)
        assert error.value.skew_s == pytest.approx(3.0)


def test_udp_receiver_arrival_timestamps_and_empty_buffer():
    clock = _ManualClock()
    with UdpPoseReceiver("127.0.0.1", 0, timestamps="arrival", clock=clock) as receiver, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        with pytest.raises(StaleDataError, match="no packet received yet"):
            receiver.latest(max_age_s=1.0)
        clock.now = 7.5
        pose = jaxlie.SE3(wxyz_xyz=np.array([1.0, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0]))
        send_pose(sender, receiver.address, PoseSample(timestamp_s=1234.0, T_world_gripper=pose))
        _wait_for(lambda: receiver.received_packets == 1)
        assert receiver.latest(max_age_s=0.1).timestamp_s == 7.5
