"""``import_bag`` / ``tactojax import-bag`` on real bag files written by ``rosbags``' own writers:
ROS 2 sqlite3, ROS 2 MCAP (and its .mcap file alone), ROS 1; then ``tactojax map`` on the import.

The session: simulated grasps of the gum box (turn 0), replayed on a ROS timeline as a robot cell
would publish them (``tests/rosbag_writer.py``).
"""

import json

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbag_writer import RAW_OFFSET, T0_S, timeline, write_bag  # noqa: E402  (tests/)

from tactojax.cli import main  # noqa: E402
from tactojax.hardware import BagError, GraspDetection, detect_grasps, import_bag  # noqa: E402
from tactojax.io import load_tactile_map, open_dataset, save_shape_model  # noqa: E402
from tactojax.objects import get_object  # noqa: E402
from tactojax.sensor import render_image  # noqa: E402
from tactojax.simulate import MappingProtocol, mapping_plan, simulate_grasps  # noqa: E402


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
