"""Write a tactile session as a real ROS bag with ``rosbags``' own writers (ROS 2 sqlite3 or MCAP, ROS 1).

A session is a dict of ``images`` (N, H, W, 3) uint8, ``openings`` (N,) mm, ``poses`` (N, 7)
``T_world_gripper`` wxyz_xyz in mm, and ``background`` (H, W, 3) uint8, the frame with no contact.
It is replayed on a ROS timeline as a robot cell would publish it: a 30 Hz tactile camera (no
contact between grasps), 100 Hz joint states of a two-finger gripper (open, close onto the
object, hold, open) and 100 Hz gripper poses in metres, one grasp every ``GRASP_PERIOD_S``.
Used by ``tests/hardware/test_rosbag.py`` and the README's command list.
"""

import jaxlie
import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2
from rosbags.typesys import Stores, get_typestore

IMAGE_TOPIC = "/tactile/image"
POSE_TOPIC = "/robot/gripper_pose"
GRIPPER_TOPIC = "/gripper/joint_states"
T0_S = 1_700_000_000.0  # an epoch time, as real stamps are
GRASP_PERIOD_S = 2.0
OPEN_MM = 80.0
RAW_OFFSET = (12, 7)  # where the gel sits in the raw camera frame (x, y), px


def timeline(session):
    """(times, opening mm, pose index) at 100 Hz, and (times, image index or -1) at 30 Hz."""
    n = len(session["openings"])
    times = T0_S + np.arange(0, n * GRASP_PERIOD_S, 0.01)
    local = (times - T0_S) % GRASP_PERIOD_S
    grasp = np.minimum(((times - T0_S) // GRASP_PERIOD_S).astype(int), n - 1)
    held = session["openings"][grasp]
    closing = np.clip((local - 0.2) / 0.3, 0, 1)
    opening_again = np.clip((local - 1.2) / 0.3, 0, 1)
    widths = OPEN_MM + (held - OPEN_MM) * closing + (OPEN_MM - held) * opening_again
    frame_times = T0_S + np.arange(0, n * GRASP_PERIOD_S, 1 / 30)
    frame_local = (frame_times - T0_S) % GRASP_PERIOD_S
    frame_grasp = np.minimum(((frame_times - T0_S) // GRASP_PERIOD_S).astype(int), n - 1)
    shown = np.where((frame_local >= 0.5) & (frame_local < 1.2), frame_grasp, -1)
    return times, widths, grasp, frame_times, shown


def write_bag(path, session, *, kind, pose="topic", image="rgb8", pose_shift_s=0.0, pose_window=(0.0, 2.0),
              raw=False):
    """A bag of the session: kind 'sqlite3' | 'mcap' | 'ros1'; pose 'topic' (PoseStamped) or 'tf'.

    Poses are published only within ``pose_window`` of each grasp period (s) and stamped
    ``pose_shift_s`` late.
    """
    ros1 = kind == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    types = store.types
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=(
        StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3))
    image_type = "sensor_msgs/msg/CompressedImage" if image == "png" else "sensor_msgs/msg/Image"

    def header(t, frame_id):
        sec, nanosec = int(t), int(round((t - int(t)) * 1e9))
        stamp = types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
        extra = {"seq": 0} if ros1 else {}
        return types["std_msgs/msg/Header"](**extra, stamp=stamp, frame_id=frame_id)

    def transform(wxyz_xyz_mm):
        q, t = wxyz_xyz_mm[:4], wxyz_xyz_mm[4:] / 1000.0
        return (types["geometry_msgs/msg/Vector3"](x=t[0], y=t[1], z=t[2]),
                types["geometry_msgs/msg/Quaternion"](x=q[1], y=q[2], z=q[3], w=q[0]))

    def image_message(t, rgb):
        if raw:  # the gel inside a larger raw camera frame (needs --corners)
            canvas = np.full((rgb.shape[0] + 20, rgb.shape[1] + 30, 3), 40, np.uint8)
            canvas[RAW_OFFSET[1]:RAW_OFFSET[1] + rgb.shape[0], RAW_OFFSET[0]:RAW_OFFSET[0] + rgb.shape[1]] = rgb
            rgb = canvas
        if image == "png":
            import cv2
            data = np.frombuffer(cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))[1], np.uint8)
            return types[image_type](header=header(t, "gel"), format="png", data=data)
        pixels = {"rgb8": rgb, "bgr8": rgb[..., ::-1], "mono16": np.zeros(rgb.shape[:2] + (2,), np.uint8)}[image]
        return types[image_type](header=header(t, "gel"), height=rgb.shape[0], width=rgb.shape[1],
                                 encoding=image, is_bigendian=0, step=pixels.shape[1] * pixels.shape[2],
                                 data=np.ascontiguousarray(pixels).reshape(-1))

    times, widths, grasp, frame_times, shown = timeline(session)
    poses = session["poses"]
    T_world_base = np.array([np.cos(0.3), 0, 0, np.sin(0.3), 100.0, -50.0, 20.0])  # static, mm
    messages = []  # (receive time, topic, message)
    for t, width, k in zip(times, widths, grasp):
        finger = width / 2 / 1000.0
        messages.append((t, GRIPPER_TOPIC, types["sensor_msgs/msg/JointState"](
            header=header(t, ""), name=["finger_left", "finger_right"], position=np.array([finger, finger]),
            velocity=np.zeros(2), effort=np.zeros(2))))
        stamp = t + pose_shift_s
        if not pose_window[0] <= (t - T0_S) % GRASP_PERIOD_S < pose_window[1]:
            continue
        if pose == "topic":
            translation, rotation = transform(poses[k])
            pose_message = types["geometry_msgs/msg/Pose"](
                position=types["geometry_msgs/msg/Point"](x=translation.x, y=translation.y, z=translation.z),
                orientation=rotation)
            messages.append((t, POSE_TOPIC, types["geometry_msgs/msg/PoseStamped"](
                header=header(stamp, "world"), pose=pose_message)))
        else:
            T_base_flange = jaxlie.SE3(T_world_base).inverse() @ jaxlie.SE3(poses[k])
            translation, rotation = transform(np.asarray(T_base_flange.wxyz_xyz, np.float64))
            messages.append((t, "/tf", types["tf2_msgs/msg/TFMessage"](transforms=[
                types["geometry_msgs/msg/TransformStamped"](
                    header=header(stamp, "robot_base"), child_frame_id="flange",
                    transform=types["geometry_msgs/msg/Transform"](translation=translation, rotation=rotation))])))
    if pose == "tf":
        translation, rotation = transform(T_world_base)
        messages.append((T0_S, "/tf_static", types["tf2_msgs/msg/TFMessage"](transforms=[
            types["geometry_msgs/msg/TransformStamped"](
                header=header(T0_S, "world"), child_frame_id="robot_base",
                transform=types["geometry_msgs/msg/Transform"](translation=translation, rotation=rotation))])))
    for t, k in zip(frame_times, shown):
        rgb = session["background"] if k < 0 else session["images"][k]
        messages.append((t + 0.004, IMAGE_TOPIC, image_message(t, rgb)))  # received 4 ms after capture
    messages.sort(key=lambda m: m[0])
    with writer:
        connections = {}
        for _, topic, message in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, message.__msgtype__, typestore=store)
        for t, topic, message in messages:
            writer.write(connections[topic], int(round(t * 1e9)), serialize(message, message.__msgtype__))
    return path
