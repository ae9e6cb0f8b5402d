"""``import_bag`` / ``tactojax import-bag`` on real bag files written by ``rosbags``' own writers:
ROS 2 sqlite3, ROS 2 MCAP (and its .mcap file alone), ROS 1; then ``tactojax map`` on the import.

The session: simulated grasps of the gum box (turn 0), replayed on a ROS timeline as a robot cell
would publish them: a 30 Hz tactile camera (no contact between grasps), 100 Hz joint states of a
two-finger gripper (open, close onto the object, hold, open) and 100 Hz gripper poses in metres.
"""

import json

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from tactojax.cli import main  # noqa: E402
from tactojax.hardware import BagError, GraspDetection, detect_grasps, import_bag  # noqa: E402
from tactojax.io import load_tactile_map, open_dataset, save_shape_model  # noqa: E402
from tactojax.objects import get_object  # noqa: E402
from tactojax.sensor import render_image  # noqa: E402
from tactojax.simulate import MappingProtocol, mapping_plan, simulate_grasps  # noqa: E402

T0_S = 1_700_000_000.0  # an epoch time, as real stamps are
GRASP_PERIOD_S = 2.0
OPEN_MM = 80.0
RAW_OFFSET = (12, 7)  # where the gel sits in the raw camera frame (x, y), px


@pytest.fixture(scope="module")
def session(small_spec):
    """Five simulated grasps that touch the gum box: images (uint8), openings (mm), T_world_gripper (mm)."""
    obj = get_object("gum_box")
    plan = mapping_plan(obj, MappingProtocol(grid_mm=15.0, yaws_deg=(0.0,), turns_deg=(0.0,)))
    result = jax.device_get(simulate_grasps(jax.random.key(3), small_spec, obj, jaxlie.SE3.identity(),
                                            plan.T_world_gripper))
    valid = np.flatnonzero(np.asarray(result.valid))[:5]
    assert len(valid) == 5
    images = np.round(np.clip(np.asarray(result.imprint.image)[valid], 0, 1) * 255).astype(np.uint8)
    background = np.round(np.clip(np.asarray(render_image(small_spec, jnp.zeros(small_spec.shape))), 0, 1)
                          * 255).astype(np.uint8)
    return {"images": images, "openings": np.asarray(result.imprint.opening)[valid].astype(np.float64),
            "poses": np.asarray(result.imprint.T_world_gripper.wxyz_xyz)[valid].astype(np.float64),
            "background": background}


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
        messages.append((t, "/gripper/joint_states", types["sensor_msgs/msg/JointState"](
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
            messages.append((t, "/robot/gripper_pose", types["geometry_msgs/msg/PoseStamped"](
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
        messages.append((t + 0.004, "/tactile/image", image_message(t, rgb)))  # received 4 ms after capture
    messages.sort(key=lambda m: m[0])
    with writer:
        connections = {}
        for _, topic, message in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, message.__msgtype__, typestore=store)
        for t, topic, message in messages:
            writer.write(connections[topic], int(round(t * 1e9)), serialize(message, message.__msgtype__))
    return path


def check_import(out, session, *, shift_mm=None):
    """The records hold the session's images, openings and poses (mm) in grasp order."""
    records = open_dataset(out).read()
    assert len(records["image"]) == len(session["images"])
    np.testing.assert_array_equal(records["image"], session["images"])
    np.testing.assert_allclose(records["opening_mm"], session["openings"], atol=1e-3)
    np.testing.assert_allclose(records["T_world_gripper"][:, 4:], session["poses"][:, 4:], atol=1e-3)
    # Rotations equal up to the quaternion's sign.
    dots = np.abs(np.sum(records["T_world_gripper"][:, :4] * session["poses"][:, :4], axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-5)
    assert np.all(np.diff(records["timestamp_s"]) > 0) and np.all(records["object_id"] == "gum_box")
    assert open_dataset(out).metadata["sensor"]["name"] == "gelslim"


@pytest.mark.parametrize("kind", ["sqlite3", "mcap"])
def test_ros2_bags_import_one_touch_per_grasp(tmp_path, session, small_spec, kind):
    bag = write_bag(tmp_path / f"session_{kind}", session, kind=kind, pose="tf" if kind == "mcap" else "topic")
    pose = {"tf_frames": ("world", "flange")} if kind == "mcap" else {"pose_topic": "/robot/gripper_pose"}
    summary = import_bag(bag, tmp_path / "out", small_spec, image_topic="/tactile/image",
                         gripper_topic="/gripper/joint_states", object_id="gum_box", progress=False, **pose)
    assert (summary.grasps, summary.recorded, summary.stale, summary.missed) == (5, 5, 0, 0)
    assert summary.image_messages == len(timeline(session)[3])
    check_import(tmp_path / "out", session)
    if kind == "sqlite3":  # the bag's receive times (images 4 ms late) pick and pair the same touches
        import_bag(bag, tmp_path / "receive", small_spec, image_topic="/tactile/image", stamps="receive",
                   gripper_topic="/gripper/joint_states", object_id="gum_box", progress=False, **pose)
        check_import(tmp_path / "receive", session)
    if kind == "mcap":  # the .mcap storage file alone is an MCAP file
        (mcap,) = bag.glob("*.mcap")
        import_bag(mcap, tmp_path / "from_file", small_spec, image_topic="/tactile/image",
                   gripper_topic="/gripper/joint_states", object_id="gum_box", progress=False, **pose)
        check_import(tmp_path / "from_file", session)
        with pytest.raises(BagError, match=r"TF has no chain from 'world' to 'tool0'.*flange, robot_base, world"):
            import_bag(mcap, tmp_path / "c", small_spec, image_topic="/tactile/image", tf_frames=("world", "tool0"),
                       gripper_topic="/gripper/joint_states", progress=False)


def test_ros1_bag_with_raw_frames_and_the_cli_then_map(tmp_path, session, lookup_model, capsys):
    bag = write_bag(tmp_path / "session.bag", session, kind="ros1", image="png", raw=True)
    x, y = RAW_OFFSET
    height, width = session["images"].shape[1:3]
    corners = [x - 0.5, y - 0.5, x + width - 0.5, y - 0.5, x + width - 0.5, y + height - 0.5, x - 0.5, y + height - 0.5]
    out, report = tmp_path / "gum_box", tmp_path / "import.json"
    assert main(["import-bag", str(bag), "--image-topic", "/tactile/image", "--pose-topic", "/robot/gripper_pose",
                 "--gripper-topic", "/gripper/joint_states", "--gripper-joints", "finger_left", "finger_right",
                 "--object-id", "gum_box", "--corners", ",".join(f"{c:g}" for c in corners), "--scale", "0.25",
                 "--out", str(out), "--json", str(report), "--no-progress"]) == 0
    assert "touches written" in capsys.readouterr().out
    result = json.loads(report.read_text())
    assert result["recorded"] == 5 and result["stale"] == 0 and result["span_s"]["pose"][0] == pytest.approx(T0_S)
    check_import(out, session)

    model = save_shape_model(tmp_path / "lookup.msgpack", lookup_model)
    assert main(["map", str(out), "--model", str(model), "--out", str(tmp_path / "gum_box.npz"), "--points", "256",
                 "--no-progress"]) == 0
    tactile_map = load_tactile_map(tmp_path / "gum_box.npz")
    assert tactile_map.object_id == "gum_box" and len(tactile_map) == 5
    assert int(tactile_map.imprint_valid.sum()) == 5 and int(tactile_map.point_valid.sum()) > 5 * 50
    assert "distance to true surface" in capsys.readouterr().out


def test_grasp_detection_and_a_miss():
    t = np.arange(0, 3, 0.01)
    width = np.interp(t, [0, 0.2, 0.5, 1.2, 1.5, 1.7, 2.0, 2.6, 2.9], [80, 80, 30, 30, 80, 80, 0.2, 0.2, 80])
    grasps = detect_grasps(np.column_stack([t, width]), GraspDetection(settle_s=0.1))
    assert [round(start, 2) for start, _ in grasps] == [0.5, 2.0]
    assert grasps[0][1] == pytest.approx(30.0) and grasps[1][1] == pytest.approx(0.2)  # the second holds nothing


@pytest.fixture(scope="module")
def good_bag(tmp_path_factory, session):
    return write_bag(tmp_path_factory.mktemp("bags") / "good.bag", session, kind="ros1")


def run_import(bag, out, spec, **overrides):
    arguments = {"image_topic": "/tactile/image", "gripper_topic": "/gripper/joint_states",
                 "pose_topic": "/robot/gripper_pose", "progress": False, **overrides}
    return import_bag(bag, out, spec, **arguments)


def test_a_missing_topic_is_named_with_the_bag_s_topics(good_bag, tmp_path, small_spec):
    with pytest.raises(BagError, match=r"no image topic '/camera/tactile'.*/tactile/image \(sensor_msgs/msg/Image\)"):
        run_import(good_bag, tmp_path / "a", small_spec, image_topic="/camera/tactile")
    with pytest.raises(BagError, match=r"no pose topic '/pose'"):
        run_import(good_bag, tmp_path / "b", small_spec, pose_topic="/pose")
    with pytest.raises(BagError, match=r"gripper topic '/robot/gripper_pose' holds geometry_msgs/msg/PoseStamped"):
        run_import(good_bag, tmp_path / "c", small_spec, gripper_topic="/robot/gripper_pose")
    with pytest.raises(BagError, match=r"has no /tf or /tf_static topic to chain world -> flange"):
        run_import(good_bag, tmp_path / "d", small_spec, pose_topic=None, tf_frames=("world", "flange"))
    from tactojax.hardware import GripperJoints
    with pytest.raises(BagError, match=r"no joint 'panda_finger_joint1'.*finger_left, finger_right"):
        run_import(good_bag, tmp_path / "e", small_spec, joints=GripperJoints(("panda_finger_joint1",)))
    assert not (tmp_path / "a").exists() and not (tmp_path / "e").exists()


def test_an_unsupported_encoding_names_the_topic(tmp_path, session, small_spec):
    bag = write_bag(tmp_path / "mono16", session, kind="sqlite3", image="mono16")
    with pytest.raises(BagError, match=r"image topic '/tactile/image': unsupported encoding 'mono16'"):
        run_import(bag, tmp_path / "out", small_spec)


@pytest.mark.parametrize("kind", ["ros1", "mcap", "sqlite3"])
def test_a_truncated_file_is_named(tmp_path, session, small_spec, kind, capsys):
    bag = write_bag(tmp_path / ("session.bag" if kind == "ros1" else "session"), session, kind=kind)
    (storage,) = [bag] if kind == "ros1" else [p for p in bag.iterdir() if p.suffix in (".mcap", ".db3")]
    storage.write_bytes(storage.read_bytes()[: storage.stat().st_size // 2])
    with pytest.raises(BagError, match="cannot be read as a ROS bag") as error:
        run_import(storage, tmp_path / "out", small_spec)
    assert storage.name in str(error.value)
    assert main(["import-bag", str(storage), "--image-topic", "/tactile/image", "--pose-topic", "/p",
                 "--gripper-topic", "/g", "--out", str(tmp_path / "cli"), "--no-progress"]) == 2
    assert storage.name in capsys.readouterr().err


def test_poses_that_never_overlap_the_images_are_refused(tmp_path, session, small_spec):
    bag = write_bag(tmp_path / "late", session, kind="sqlite3", pose_shift_s=3600.0)
    with pytest.raises(BagError, match=r"pose topic '/robot/gripper_pose' spans .* never overlaps the image topic"):
        run_import(bag, tmp_path / "out", small_spec)
    assert not (tmp_path / "out").exists()
    # Poses only while the arm moves between grasps: they overlap the bag but no touch is within the skew.
    bag = write_bag(tmp_path / "between", session, kind="sqlite3", pose_window=(1.5, 2.0))
    with pytest.raises(BagError, match=r"no touch could be taken.*pose topic '/robot/gripper_pose' is stale"):
        run_import(bag, tmp_path / "out", small_spec)
    assert not (tmp_path / "out").exists()
