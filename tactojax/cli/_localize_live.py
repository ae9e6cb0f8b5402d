"""``tactojax localize-live --camera SRC --map MAP...``: the pose belief on every camera frame, fused over grasps."""

from __future__ import annotations

from tactojax.cli._map import DEFAULT_MODEL
from tactojax.cli._maps import add_encoder_argument, camera_source, maps_and_query_encoder
from tactojax.localize._identify_episodes import OBJECT_TOLERANCE

LIVE_READ_AHEAD = 4
"""Frames each camera is decoded ahead when every frame is processed (a video file, --every-frame)."""


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "localize-live", help="identify and localize the grasped object from a live tactile camera",
        description="Compile the whole touch (heightmap, features, every map's pose belief) once, then run "
                    "it on every frame of a camera, video file or stream, with the gripper opening from a "
                    "WSG-50 or a fixed value and, with --pose, the gripper pose at each frame from the robot's "
                    "feed or a log. Each grasp updates the belief once it settles; with poses, successive "
                    "grasps of an object that stays put fuse into one belief (P(object), the object's pose in "
                    "the world, P(within 2 mm)). Between updates the pose is tracked from frame to frame "
                    "(registration from the previous pose; a new belief only when the fit degrades or contact "
                    "is lost). Prints the estimates and the sustained rate and latency.")
    parser.add_argument("--camera", required=True,
                        help="camera device index, video file, or stream URL (frames must show the gel; "
                             "see --corners)")
    parser.add_argument("--second-camera", metavar="SRC",
                        help="the opposite finger's tactile camera, when it carries a sensor (same kinds of source "
                             "and --corners as --camera): read in step with --camera, each grasp's belief "
                             "update then fuses both fingers")
    parser.add_argument("--map", nargs="+", required=True, dest="maps", metavar="MAP", help="object maps (.npz) or map catalogs")
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--opening", type=float, help="fixed gripper opening, mm")
    source.add_argument("--gripper", metavar="URL",
                        help="WSG-50 to read the opening from: a serial port or socket://HOST:PORT")
    parser.add_argument("--pose", metavar="SOURCE",
                        help="gripper poses T_world_gripper: udp://HOST:PORT (the robot's feed, see "
                             "tactojax.hardware.send_pose) or a CSV/JSON pose log on the video's clock; without "
                             "it, grasps cannot be related and each starts a new belief")
    parser.add_argument("--max-skew-ms", type=float, default=50.0,
                        help="largest time between a frame and its pose, ms (default 50; a frame without a pose "
                             "that close is localized without one and counted as stale)")
    parser.add_argument("--time-offset-s", type=float, default=0.0,
                        help="added to every frame time: a video file's first frame on the pose log's clock")
    parser.add_argument("--corners", metavar="X,Y,...",
                        help="gel corners in the raw image, 8 numbers: top-left, top-right, bottom-right, "
                             "bottom-left (x, y) pixels; the frame is rectified to the sensor's image")
    parser.add_argument("--model", default=DEFAULT_MODEL, help=f"shape model (default {DEFAULT_MODEL})")
    add_encoder_argument(parser)
    parser.add_argument("--no-tracking", action="store_true",
                        help="report the belief on every frame, moved with the gripper, without tracking (default: "
                             "track the pose between frames)")
    parser.add_argument("--object-tolerance", type=float, default=OBJECT_TOLERANCE, metavar="P",
                        help="P(object) a grasp may drop: after each grasp the least probable maps that together "
                             f"hold at most P are no longer updated until the localizer resets (default "
                             f"{OBJECT_TOLERANCE}; 0: every map)")
    parser.add_argument("--frames", type=int, default=None, help="stop after this many frames")
    parser.add_argument("--every-frame", action="store_true",
                        help="process every frame in order (default for video files); otherwise always the "
                             "newest frame, skipping those that arrive while a touch is processed")
    parser.add_argument("--json", metavar="PATH", help="write every estimate and the run's statistics as JSON")
    parser.add_argument("--view", nargs="?", const="spawn", choices=["spawn", "serve"],
                        help="stream the maps and every estimate to a rerun viewer: spawn one (default) or serve "
                             "the web viewer on localhost:9090 (needs the viz extra)")
    parser.add_argument("--view-save", metavar="FILE.rrd", help="stream them to a rerun recording file instead")
    parser.set_defaults(run=run)


def parse_corners(text: str | None):
    """Eight comma-separated numbers -> (4, 2) corners, or None."""
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"--corners must be 8 comma-separated numbers, got {text!r}") from None
    if len(values) != 8:
        raise ValueError(f"--corners needs 8 numbers (4 corners x, y), got {len(values)}")
    return [values[i:i + 2] for i in range(0, 8, 2)]


def run(args) -> int:
    from pathlib import Path

    import numpy as np
    from tqdm.auto import tqdm

    from tactojax import CompilationCounter
    from tactojax.cli._maps import stored_calibration
    from tactojax.cli._record import open_pose_source
    from tactojax.cli._table import write_json
    from tactojax.hardware import WSG50, LiveStatistics, OpenCVCamera, live_estimates
    from tactojax.hardware._live import PoseLookup
    from tactojax.io import expand_catalogs, resolve_shape_model, stored_surface
    from tactojax.localize import LiveSettings, Localizer, Tracker

    if args.opening is not None and (not np.isfinite(args.opening) or args.opening <= 0):
        raise ValueError(f"--opening must be a positive number of mm, got {args.opening}")
    if not args.max_skew_ms > 0:
        raise ValueError(f"--max-skew-ms must be positive, got {args.max_skew_ms}")
    model = resolve_shape_model(args.model)
    args.maps = expand_catalogs(args.maps)
    maps, encoder = maps_and_query_encoder(args.maps, args.encoder)
    calibrations = [stored_calibration(path, args.encoder) for path in args.maps]
    print("compiling the touch program ...", flush=True)
    source = camera_source(args.camera)
    every_frame = args.every_frame or (isinstance(source, str) and Path(source).is_file())
    # From a live camera, settled grasps update the belief in a worker thread, so that no frame
    # waits for it; a video file is read frame by frame (decoded ahead in a thread), each update
    # in its frame.
    localizer = (Localizer if args.no_tracking else Tracker)(maps, model, encoder, calibrations=calibrations,
                                                             surfaces=[stored_surface(p) for p in args.maps],
                                                             live=LiveSettings(background_update=not every_frame,
                                                                               object_tolerance=args.object_tolerance))
    print(f"compiled in {localizer.compile_s:.1f} s for {', '.join(localizer.object_ids)}"
          f"{'' if args.no_tracking else ' (tracking between frames)'}")
    poses = open_pose_source(args.pose) if args.pose else None
    lookup = PoseLookup(poses, max_skew_s=args.max_skew_ms / 1e3) if poses is not None else None
    view, gripper, second_camera = None, None, None
    statistics, records = LiveStatistics(), []
    try:
        view = _open_view(args, maps)
        gripper = WSG50(args.gripper) if args.gripper else None
        opening = gripper.opening_mm if gripper is not None else args.opening
        if args.second_camera is not None:
            second_camera = OpenCVCamera(camera_source(args.second_camera), localizer.image_shape[:2],
                                         corners=parse_corners(args.corners), time_offset_s=args.time_offset_s)
        with OpenCVCamera(source, localizer.image_shape[:2], corners=parse_corners(args.corners),
                          time_offset_s=args.time_offset_s) as camera, CompilationCounter() as compiles:
            bar = tqdm(live_estimates(camera, localizer, opening, gripper_pose=lookup, second_camera=second_camera,
                                      max_frames=args.frames, latest_only=not every_frame,
                                      read_ahead=LIVE_READ_AHEAD if every_frame else 0),
                       total=args.frames, unit="frame")
            for frame, estimate in bar:
                statistics.add(frame, estimate)
                bar.set_postfix_str(_progress(estimate))
                pose = None if lookup is None or lookup.last is None else np.asarray(lookup.last.wxyz_xyz).tolist()
                records.append({"frame": frame.index, "timestamp_s": frame.timestamp_s,
                                "T_world_gripper_wxyz_xyz": pose, **estimate.as_dict()})
                if view is not None:
                    from tactojax.viz import log_live_estimate
                    log_live_estimate(view, frame.index, records[-1], image=frame.image)
        statistics.recompilations = compiles.count
        statistics.stale_poses = lookup.stale if lookup is not None else 0
    finally:
        localizer.close()
        if gripper is not None:
            gripper.close()
        if second_camera is not None:
            second_camera.close()
        if poses is not None and hasattr(poses, "close"):
            poses.close()
        if view is not None:
            view.flush()
            view.disconnect()
    summary = _print_summary(records, statistics, localizer, lookup, args)
    if args.json:
        write_json(args.json, {"maps": list(localizer.object_ids), "method": "belief",
                               "tracking": not args.no_tracking, "pose_source": args.pose,
                               "calibrated": [c is not None for c in calibrations],
                               "compile_s": localizer.compile_s, "summary": summary, "estimates": records})
    return 0


def _progress(estimate) -> str:
    """The progress bar's words for one estimate."""
    if estimate.object_id is None:
        return "contact, no grasp settled yet" if estimate.contact else "no contact"
    probability = estimate.object_probabilities[estimate.object_id]
    return (f"{estimate.object_id} P {probability:.2f}, within 2 mm {estimate.probability_within:.2f}, "
            f"{estimate.grasps} grasp{'s' * (estimate.grasps != 1)}{', tracked' if estimate.tracked else ''}")


def _open_view(args, maps):
    """A rerun recording with the maps logged, for --view / --view-save, or None."""
    if args.view is None and args.view_save is None:
        return None
    if args.view is not None and args.view_save is not None:
        raise ValueError("give --view or --view-save, not both")
    from tactojax.viz import log_maps, open_recording

    recording, url = open_recording(save=args.view_save, serve=args.view == "serve", spawn=args.view == "spawn")
    log_maps(recording, maps)
    if url:
        print(f"web viewer: {url}", flush=True)
    return recording


def _print_summary(records: list[dict], statistics, localizer, lookup, args) -> dict:
    """Print the last frame's estimate and the run's figures (rate, latency, skipped frames,
    recompilations); returns :meth:`~tactojax.hardware.LiveStatistics.summary`."""
    from tactojax.cli._table import format_table

    summary = statistics.summary()
    estimated = [record for record in records if record["object_id"] is not None]
    if estimated:
        last = estimated[-1]
        probability = last["object_probabilities"][last["object_id"]]
        rows = [["frame", last["frame"]], ["object (P(object))", f"{last['object_id']} ({probability:.3f})"],
                ["P(within 2 mm)", last["probability_within_2mm"]], ["grasps fused", last["grasps"]]]
        if last["T_object_sensor_wxyz_xyz"] is not None:
            rows.append(["sensor pose in object (wxyz, xyz mm)",
                         ", ".join(f"{v:.2f}" for v in last["T_object_sensor_wxyz_xyz"])])
        if last["T_world_object_wxyz_xyz"] is not None and lookup is not None:
            rows.append(["object pose in world (wxyz, xyz mm)",
                         ", ".join(f"{v:.2f}" for v in last["T_world_object_wxyz_xyz"])])
        print(format_table(["last frame with an estimate", "value"], rows))
    touched = sum(record["contact"] for record in records)
    print(format_table(["run", "value"], [
        ["frames (without contact)", f"{summary['frames']} ({len(records) - touched})"],
        ["grasps fused into the belief", sum(record["updated"] for record in records)],
        ["sustained rate (Hz)", summary["rate_hz"]],
        ["latency median / p95 (ms)", f"{summary['latency_ms']['median']:.1f} / {summary['latency_ms']['p95']:.1f}"],
        ["skipped / dropped frames", f"{summary['skipped_frames']} / {summary['dropped_frames']}"],
        *([] if lookup is None else [["frames without a pose (stale)", summary["stale_poses"]]]),
        ["recompilations", summary["recompilations"]], ["compile at start-up (s)", localizer.compile_s],
        *([] if args.no_tracking else [["frames tracked / beliefs started",
                                        f"{localizer.tracked_frames} / {localizer.relocalizations}"]]),
    ]))
    if lookup is not None and lookup.stale:
        print(f"note: {lookup.stale} frames had no gripper pose within {args.max_skew_ms:g} ms ({lookup.last_error})")
    return summary
