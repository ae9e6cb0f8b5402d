"""``tactojax import-bag BAG --image-topic T (--pose-topic T | --tf PARENT CHILD) --gripper-topic T --out DIR``."""

from __future__ import annotations


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "import-bag", help="import a recorded ROS 1/2 bag or MCAP file into a dataset",
        description="Read the tactile images, the gripper pose (a PoseStamped topic or the TF chain PARENT -> "
                    "CHILD) and the gripper opening (a JointState topic) from a ROS 1 bag, a ROS 2 bag "
                    "(sqlite3 or MCAP) or an MCAP file, and write one touch per grasp as `tactojax record` "
                    "does: same pairing and maximum skew, stale touches refused, frames rectified with "
                    "--corners. `tactojax map DIR` builds the map. ROS lengths (m) become mm.")
    parser.add_argument("bag", help="a .bag file, a ROS 2 bag directory, or a .mcap / .db3 file")
    parser.add_argument("--out", required=True, help="dataset directory to create")
    parser.add_argument("--image-topic", required=True, help="sensor_msgs/Image or CompressedImage topic")
    pose = parser.add_mutually_exclusive_group(required=True)
    pose.add_argument("--pose-topic", help="geometry_msgs/PoseStamped topic of the gripper pose in the world")
    pose.add_argument("--tf", nargs=2, metavar=("PARENT", "CHILD"),
                      help="gripper pose from /tf and /tf_static: the world frame PARENT, the gripper frame CHILD")
    parser.add_argument("--gripper-topic", required=True, help="sensor_msgs/JointState topic of the gripper")
    parser.add_argument("--gripper-joints", nargs="+", default=[], metavar="JOINT",
                        help="joints whose absolute positions sum to the opening (default: every joint of the "
                             "message; Franka Hand: panda_finger_joint1 panda_finger_joint2)")
    parser.add_argument("--joint-scale", type=float, default=1000.0,
                        help="joint position unit to mm (default 1000: metres)")
    parser.add_argument("--opening-offset-mm", type=float, default=0.0,
                        help="added to the summed joints: the gap between the gel surfaces minus the jaw width, mm")
    parser.add_argument("--gripper-frame", metavar="QW,QX,QY,QZ,X,Y,Z",
                        help="tactojax's gripper frame (midway between the gels, z approach, y towards the sensor "
                             "finger) in the recorded pose's frame, translation in mm (default identity)")
    parser.add_argument("--object-id", help="name of the object in the records (default: the bag's name)")
    parser.add_argument("--corners", metavar="X,Y,...", help="gel corners in the raw image (8 numbers: TL, TR, BR, BL)")
    parser.add_argument("--sensor", choices=["gelslim", "gelsight", "gelsight_mini"], default="gelslim")
    parser.add_argument("--scale", type=float, default=0.5, help="sensor resolution factor (default 0.5)")
    parser.add_argument("--touches", choices=["grasps", "every-frame"], default="grasps",
                        help="one touch per grasp found in the openings (default), or every image message")
    parser.add_argument("--settle-s", type=float, default=0.1,
                        help="the gripper holds still this long before a grasp's frame is taken, s (default 0.1)")
    parser.add_argument("--max-skew-ms", type=float, default=50.0,
                        help="largest time between a frame and its opening and pose, ms (default 50)")
    parser.add_argument("--stamps", choices=["header", "receive"], default="header",
                        help="message header stamps (default) or the bag's receive times")
    parser.add_argument("--append", action="store_true", help="add to an existing dataset")
    parser.add_argument("--json", metavar="PATH", help="write the import's counts and spans as JSON")
    parser.add_argument("--no-progress", action="store_true")
    parser.set_defaults(run=run)


def parse_pose(text: str | None):
    """Seven comma-separated numbers qw,qx,qy,qz,x,y,z (mm) -> a jaxlie.SE3, or None."""
    if text is None:
        return None
    import jaxlie
    import numpy as np

    try:
        values = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise ValueError(f"--gripper-frame must be 7 comma-separated numbers, got {text!r}") from None
    if values.shape != (7,) or not np.all(np.isfinite(values)) or abs(np.linalg.norm(values[:4]) - 1) > 1e-3:
        raise ValueError(f"--gripper-frame needs qw,qx,qy,qz (a unit quaternion) and x,y,z in mm, got {text!r}")
    return jaxlie.SE3(values)


def run(args) -> int:
    from tactojax.cli._localize_live import parse_corners
    from tactojax.cli._table import format_table, write_json
    from tactojax.hardware import GraspDetection, GripperJoints, import_bag
    from tactojax.sensor import sensor_preset

    spec = sensor_preset(args.sensor, scale=args.scale)
    summary = import_bag(
        args.bag, args.out, spec, image_topic=args.image_topic, gripper_topic=args.gripper_topic,
        pose_topic=args.pose_topic, tf_frames=tuple(args.tf) if args.tf else None, object_id=args.object_id,
        corners=parse_corners(args.corners),
        joints=GripperJoints(tuple(args.gripper_joints), args.joint_scale, args.opening_offset_mm),
        T_child_gripper=parse_pose(args.gripper_frame), touches=args.touches,
        detection=GraspDetection(settle_s=args.settle_s), max_skew_s=args.max_skew_ms / 1e3, stamps=args.stamps,
        append=args.append, progress=not args.no_progress)
    print(format_table(["import", str(args.out)], [
        ["image messages", summary.image_messages],
        ["grasps found" if args.touches == "grasps" else "frames considered", summary.grasps],
        ["touches written", summary.recorded],
        ["missed (closed on nothing)", summary.missed],
        ["dropped for stale data", summary.stale],
        ["time (s)", f"{summary.read_s:.2f}"],
    ]))
    if args.json:
        write_json(args.json, {"bag": args.bag, "out": args.out, **summary.as_dict()})
    return 0
