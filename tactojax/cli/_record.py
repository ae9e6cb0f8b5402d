"""``tactojax record --out DIR``: record touches from a real or a simulated robot cell."""

from __future__ import annotations

from tactojax.cli._active_cell import add_active_arguments
from tactojax.cli._map import DEFAULT_MODEL


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "record", help="record touches (image, opening, gripper pose) to a dataset",
        description="Real cell: watch the tactile camera, the WSG-50 and the robot's pose feed, and record "
                    "one touch each time the gripper starts holding a part (the robot is driven by your "
                    "own software). Simulated cell (--simulate OBJECT): run the mapping protocol on the "
                    "simulator through the same devices (a WSG-50 emulator, a UDP pose feed). Every "
                    "touch is on disk when it is counted; a killed recording keeps all completed touches. "
                    "With --active MAP, the simulated cell runs an active episode instead: both jaws carry a "
                    "sensor, the live localizer fuses every grasp and chooses the next by expected gain in "
                    "P(within 2 mm) until it is sure (--stop) or --max-grasps; each grasp's touch is recorded.")
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
    active = parser.add_argument_group("active episode on the simulated cell")
    active.add_argument("--active", nargs="+", metavar="MAP", help="object maps (.npz): run an active episode")
    active.add_argument("--turn-deg", type=float, default=0.0, help="the object's turn about the vertical, degrees")
    add_active_arguments(active)
    active.add_argument("--model", default=DEFAULT_MODEL, help=f"shape model (default {DEFAULT_MODEL})")
    active.add_argument("--encoder", default=None,
                        help="feature encoder (default: the features stored in the maps)")
    active.add_argument("--seed", type=int, default=0, help="placement, first grasp, proposals and sensor noise")
    active.add_argument("--figure", metavar="PNG", help="write the chosen grasps and the belief after each")
    active.add_argument("--json", metavar="PATH", help="write every executed grasp as JSON")
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
    if args.active:
        return _run_active(args, spec)
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


def _run_active(args, spec) -> int:
    from tactojax.cli._active_cell import run_simulated_active
    from tactojax.cli._maps import maps_and_query_encoder, stored_calibration
    from tactojax.cli._table import write_json
    from tactojax.hardware import Recorder
    from tactojax.io import resolve_shape_model, stored_surface
    from tactojax.objects import resolve_object

    if not args.simulate:
        raise ValueError("--active runs on the simulated cell: pass --simulate OBJECT")
    obj = resolve_object(args.simulate)
    model = resolve_shape_model(args.model)
    maps, encoder = maps_and_query_encoder(args.active, args.encoder)
    calibrations = [stored_calibration(path, args.encoder) for path in args.active]
    source = {"simulated": obj.name, "gripper": "WSG-50 emulator over TCP", "pose": "UDP", "active": list(args.active)}
    with Recorder(args.out, spec, source=source) as recorder:
        report = run_simulated_active(spec, obj, maps, model, encoder, calibrations=calibrations,
                                      surfaces=[stored_surface(path) for path in args.active],
                                      turn_deg=args.turn_deg, max_grasps=args.max_grasps, candidates=args.candidates,
                                      stop=args.stop, seed=args.seed, recorder=recorder,
                                      object_id=args.object_id or obj.name, figure=args.figure)
        recorded = len(recorder)
    print(f"recorded {recorded} touches to {args.out} (the sensor finger of every fused grasp)")
    if args.json:
        write_json(args.json, report)
    return 0
