"""``tactojax record --out DIR``: record touches from a real or a simulated robot cell."""

from __future__ import annotations


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "record", help="record touches (image, opening, gripper pose) to a dataset",
        description="Real cell: watch the tactile camera, the WSG-50 and the robot's pose feed, and record "
                    "one touch each time the gripper starts holding a part (the robot is driven by your "
                    "own software). Simulated cell (--simulate OBJECT): run the mapping protocol on the "
                    "simulator through the same devices (a WSG-50 emulator, a UDP pose feed). Every "
                    "touch is on disk when it is counted; a killed recording keeps all completed touches.")
    parser.add_argument("--out", required=True, help="dataset directory (created, or appended to)")
    parser.add_argument("--object-id", help="name of the object in the records (default: the simulated object)")
    parser.add_argument("--sensor", choices=["gelslim", "gelsight", "gelsight_mini"], default="gelslim")
    parser.add_argument("--scale", type=float, default=0.5, help="sensor resolution factor (default 0.5)")
    real = parser.add_argument_group("real cell")
    real.add_argument("--camera", help="camera device index, video file or stream URL")
    real.add_argument("--corners", metavar="X,Y,...", help="gel corners in the raw image (8 numbers: TL, TR, BR, BL)")
    real.add_argument("--gripper", metavar="URL", help="WSG-50: serial port (/dev/ttyUSB0) or socket://HOST:PORT")
    real.add_argument("--pose", metavar="SOURCE",
                      help="robot pose feed: udp://HOST:PORT (packets, see tactojax.hardware.send_pose) or a "
                           "CSV/JSON pose log (for replaying a recorded video)")
    real.add_argument("--touches", type=int, default=None, help="stop after this many touches (default: Ctrl-C)")
    real.add_argument("--max-skew-ms", type=float, default=50.0,
                      help="largest time between a frame and its opening and pose, ms (default 50)")
    simulated = parser.add_argument_group("simulated cell")
    simulated.add_argument("--simulate", metavar="OBJECT", help="catalog object or mesh to record in simulation")
    simulated.add_argument("--grid-mm", type=float, default=10.0, help="mapping grid spacing, mm (default 10)")
    simulated.add_argument("--yaws-deg", type=float, nargs="+", default=[0.0, 20.0, -20.0])
    simulated.add_argument("--turns-deg", type=float, nargs="+", default=[0.0, 90.0, 180.0, 270.0])
    parser.set_defaults(run=run)


def open_pose_source(text: str):
    """``udp://HOST:PORT`` -> a UDP receiver; anything else -> a pose log file."""
    from tactojax.hardware import UdpPoseReceiver, read_pose_log

    if text.startswith("udp://"):
        host, _, port = text[len("udp://"):].rpartition(":")
        if not port.isdigit():
            raise ValueError(f"--pose {text!r}: expected udp://HOST:PORT")
        return UdpPoseReceiver(host or "0.0.0.0", int(port))
    return read_pose_log(text)


def run(args) -> int:
    from tactojax.cli._localize_live import parse_corners
    from tactojax.cli._maps import camera_source
    from tactojax.hardware import WSG50, OpenCVCamera, Recorder, record_grasps, record_protocol, simulated_cell
    from tactojax.objects import resolve_object
    from tactojax.sensor import sensor_preset
    from tactojax.simulate import MappingProtocol, mapping_plan

    spec = sensor_preset(args.sensor, scale=args.scale)
    if args.simulate:
        obj = resolve_object(args.simulate)
        plan = mapping_plan(obj, MappingProtocol(grid_mm=args.grid_mm, yaws_deg=tuple(args.yaws_deg),
                                                 turns_deg=tuple(args.turns_deg)))
        source = {"simulated": obj.name, "gripper": "WSG-50 emulator over TCP", "pose": "UDP"}
        with simulated_cell(spec, obj) as cell, Recorder(args.out, spec, source=source) as recorder:
            summary = record_protocol(cell.robot, cell.camera, cell.gripper.opening_mm, cell.poses, plan, recorder,
                                      object_id=args.object_id or obj.name, place_object=cell.scene.place_object)
    else:
        missing = [flag for flag, value in (("--camera", args.camera), ("--gripper", args.gripper),
                                            ("--pose", args.pose), ("--object-id", args.object_id)) if not value]
        if missing:
            raise ValueError(f"a real recording needs {', '.join(missing)} (or --simulate OBJECT)")
        source = {"camera": args.camera, "corners": args.corners, "gripper": args.gripper, "pose": args.pose}
        poses = open_pose_source(args.pose)
        try:
            with OpenCVCamera(camera_source(args.camera), spec, corners=parse_corners(args.corners)) as camera, \
                    WSG50(args.gripper) as gripper, Recorder(args.out, spec, source=source) as recorder:
                summary = record_grasps(camera, gripper, poses, recorder, object_id=args.object_id,
                                        touches=args.touches, max_skew_s=args.max_skew_ms / 1e3)
        finally:
            if hasattr(poses, "close"):
                poses.close()
    print(f"recorded {summary.recorded} touches to {args.out} ({summary.missed} grasps missed the object, "
          f"{summary.stale} dropped for stale data)")
    return 0
