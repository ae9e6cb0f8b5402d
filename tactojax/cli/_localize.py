"""``tactojax localize MAP... IMAGE... --opening MM``: which object, and where, from one or several touches."""

from __future__ import annotations

from tactojax.cli._map import DEFAULT_MODEL
from tactojax.cli._maps import add_encoder_argument, maps_and_query_encoder
from tactojax.cli._table import format_table, write_json

MAP_SUFFIX = ".npz"
"""Positional arguments ending in this are maps; the others are images."""


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "localize", help="identify the object and its pose from one or several tactile images",
        description="Predict each touch's heightmap, compute its features and fuse all the touches into every "
                    "map's pose belief, the touches related by their gripper poses (the object stays put): "
                    "prints P(object) (from the beliefs' evidence, under one calibration), the object's pose "
                    "in the world, the first sensor's pose in the object frame, P(within 2 mm) and the "
                    "belief's leading modes. The belief reads each map's stored calibration (`tactojax "
                    "calibrate-belief`). --method picks one of the paper's one-touch baselines instead.",
        epilog="Several grasps: one image and one --gripper-pose per grasp, in the same order, e.g. "
               "`tactojax localize a.npz b.npz g1.png g2.png --opening 21 20.5 --gripper-pose 1 0 0 0 0 0 0 "
               "--gripper-pose 0.9848 0 0 0.1736 10 -5 0`. A gripper pose is T_world_gripper (tactojax.geometry's "
               "gripper frame) in any frame where the object stays put (the robot's base): quaternion "
               "w x y z (unit norm), then translation x y z in mm. A single image may leave it out: the "
               "world frame is then that grasp's gripper frame.")
    parser.add_argument("paths", nargs="+", metavar="PATH",
                        help=f"one or more tactile maps ({MAP_SUFFIX}) or map catalogs, then one or more tactile images (PNG/JPEG), "
                             "one per grasp")
    parser.add_argument("--opening", type=float, nargs="+", required=True, metavar="MM",
                        help="gripper opening at each grasp, mm: one for all images, or one per image")
    parser.add_argument("--gripper-pose", type=float, nargs=7, action="append", dest="gripper_poses",
                        metavar=("QW", "QX", "QY", "QZ", "X", "Y", "Z"),
                        help="T_world_gripper of a grasp (wxyz, then xyz in mm); repeat it once per image, in "
                             "order (required with several images)")
    parser.add_argument("--second-image", nargs="+", metavar="IMAGE", dest="second_images",
                        help="the opposite finger's image of each grasp (a sensor on both jaws), one per image")
    parser.add_argument("--method", default="belief",
                        help="belief (default), or a one-touch baseline of the paper: random, cti, cti-icp-N")
    parser.add_argument("--modes", type=int, default=3, help="modes of the belief to list (default 3)")
    parser.add_argument("--model", default=DEFAULT_MODEL, help=f"shape model (default {DEFAULT_MODEL})")
    add_encoder_argument(parser)
    parser.add_argument("--json", metavar="PATH", help="write the estimate as JSON")
    parser.set_defaults(run=run)


def read_image(path: str):
    """An RGB uint8 image from disk, with a clear error for a missing or unreadable file."""
    from pathlib import Path

    import cv2

    if not Path(path).is_file():
        raise FileNotFoundError(f"no image file {path}")
    image = cv2.imread(path, cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"{path} is not a readable image (corrupt, or not PNG/JPEG/BMP)")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def split_paths(paths: list[str]) -> tuple[list[str], list[str]]:
    """The positional arguments as (maps, images): maps (or map catalogs, spelt out into their
    maps) first, then images."""
    from pathlib import Path

    from tactojax.io import expand_catalogs

    is_map = [p.lower().endswith(MAP_SUFFIX) or Path(p).is_dir() for p in paths]
    maps, images = [p for p, m in zip(paths, is_map) if m], [p for p, m in zip(paths, is_map) if not m]
    if not maps or not images:
        raise ValueError(f"give at least one map ({MAP_SUFFIX} or a map catalog) and then at least one image, "
                         f"got {paths}")
    if is_map.index(False) < len(maps):
        raise ValueError(f"give the maps ({MAP_SUFFIX}) first, then the images: got {paths}")
    return expand_catalogs(maps), images


def grasp_poses(gripper_poses, count: int):
    """(count,) gripper poses as ``jaxlie.SE3`` (identity for a single grasp without one), with
    clear errors for a missing pose, a count mismatch or a non-unit quaternion."""
    import jaxlie
    import numpy as np

    if gripper_poses is None:
        if count > 1:
            raise ValueError(f"{count} images need their gripper poses: give --gripper-pose QW QX QY QZ X Y Z once "
                             "per image (the kinematics that relate the grasps)")
        return [jaxlie.SE3.identity()]
    if len(gripper_poses) != count:
        raise ValueError(f"{count} image{'s' * (count > 1)} but {len(gripper_poses)} --gripper-pose: give one pose "
                         "per image, in order")
    poses = []
    for index, values in enumerate(gripper_poses):
        pose = np.asarray(values, np.float32)
        norm = float(np.linalg.norm(pose[:4]))
        if not np.all(np.isfinite(pose)) or abs(norm - 1.0) > 1e-3:
            raise ValueError(f"--gripper-pose {index + 1}: the quaternion w x y z must be finite and of unit norm, "
                             f"got {values[:4]} (norm {norm:.4f})")
        poses.append(jaxlie.SE3(np.concatenate([pose[:4] / norm, pose[4:]])))
    return poses


def per_image(values: list[float], count: int, flag: str) -> list[float]:
    """One value per image from one value for all or one per image."""
    import numpy as np

    if len(values) not in (1, count):
        raise ValueError(f"{flag}: give one value for all {count} images or one per image, got {len(values)}")
    values = values * count if len(values) == 1 else values
    for value in values:
        if not np.isfinite(value) or value <= 0:
            raise ValueError(f"{flag} must be a positive number of mm, got {value}")
    return list(values)


def observe_image(model, image, path: str):
    """A touch's local shape from its image: (heightmap, contact mask), or a ValueError when the
    image does not fit the model or shows no contact."""
    import jax.numpy as jnp

    from tactojax.localize._localizer import observe
    from tactojax.shape import check_image

    try:
        check_image(model, image)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    _, heightmap, mask, contact = observe(model, jnp.asarray(image))  # what the live loop sees of a frame
    if not bool(contact):
        raise ValueError(f"{path} shows no contact (a dark frame, or no observed pixel above the shape model's "
                         "contact threshold): leave it out; there is nothing to localize in it")
    return heightmap, mask


def run(args) -> int:
    from tactojax.features import encode_image
    from tactojax.io import resolve_shape_model
    from tactojax.localize._baselines import parse_method

    map_paths, image_paths = split_paths(args.paths)
    method = parse_method(args.method)
    openings = per_image(args.opening, len(image_paths), "--opening")
    seconds = args.second_images
    if seconds is not None and len(seconds) != len(image_paths):
        raise ValueError(f"{len(image_paths)} images but {len(seconds)} --second-image: give one per image")
    if method.kind != "belief" and (len(image_paths) > 1 or seconds):
        raise ValueError(f"--method {method.name} is one of the paper's one-touch baselines: give one image "
                         "without --second-image, or fuse the touches with the belief (the default)")
    if args.modes < 1:
        raise ValueError(f"--modes must be at least 1, got {args.modes}")
    poses = grasp_poses(args.gripper_poses, len(image_paths))
    paths = image_paths + (seconds or [])
    images = [read_image(path) for path in paths]
    model = resolve_shape_model(args.model)
    shapes = [observe_image(model, image, path) for image, path in zip(images, paths)]
    maps, encoder = maps_and_query_encoder(map_paths, args.encoder, progress=False)
    observed = [(*shape, encode_image(encoder, image)) for shape, image in zip(shapes, images)]
    if method.kind != "belief":
        return _run_baseline(args, method, maps, image_paths[0], openings[0], observed[0])
    first, second = observed[:len(image_paths)], observed[len(image_paths):] or None
    return _run_belief(args, map_paths, maps, image_paths, openings, poses, first, second)


def _run_belief(args, map_paths, maps, image_paths, openings, poses, observed, second) -> int:
    import numpy as np

    from tactojax.cli._belief import belief_summary, position_and_angles
    from tactojax.cli._maps import stacked_localization_maps
    from tactojax.geometry import opposite_sensor_pose, sensor_pose
    from tactojax.localize import Touch, localize
    from tactojax.localize._identify_episodes import object_probabilities

    touches, T_world_sensor = [], []
    for g, (opening, T_world_gripper) in enumerate(zip(openings, poses)):
        fingers = [(observed[g], sensor_pose)] + ([(second[g], opposite_sensor_pose)] if second else [])
        for (heightmap, mask, feature), finger_pose in fingers:
            touches.append(Touch(heightmap=heightmap, mask=mask, feature=feature, opening=np.float32(opening)))
            T_world_sensor.append(finger_pose(T_world_gripper, np.float32(opening)))
    stack, calibrated = stacked_localization_maps(map_paths, maps, args.encoder)
    summaries = [belief_summary(localize(stack.window(m), touches, T_world_sensor), args.modes)
                 for m in range(len(stack))]
    probabilities = object_probabilities([s["log_evidence"] for s in summaries])
    names = [m.object_id for m in maps]
    frame = "world" if args.gripper_poses else "gripper frame"
    rows = []
    for i in np.argsort(-probabilities):
        position, angles = position_and_angles(_se3(summaries[i]["T_world_object_wxyz_xyz"]))
        rows.append([names[i], float(probabilities[i]), summaries[i]["probability_within_2mm"], position, angles])
    print(f"pose belief over {len(touches)} touch{'es' * (len(touches) > 1)} of {len(image_paths)} grasp"
          f"{'s' * (len(image_paths) > 1)}{'' if calibrated else ' (default scales: tactojax calibrate-belief fits the map its own)'}")
    print(format_table(["object", "P(object)", "P(within 2 mm)", f"object position in {frame} (mm)",
                        "roll, pitch, yaw (deg)"], rows))
    if not probabilities.any():
        print("no map explains the touches: no estimate")
        _write(args, image_paths, openings, frame, names, probabilities, summaries, None)
        return 1
    chosen = int(np.argmax(probabilities))
    best = summaries[chosen]
    sensor_position, sensor_angles = position_and_angles(_se3(best["T_object_sensor_wxyz_xyz"]))
    detail = [["object", f"{names[chosen]} (P(object) {probabilities[chosen]:.3f})"],
              ["P(within 2 mm)", best["probability_within_2mm"]],
              ["first sensor in object frame (mm)", sensor_position],
              ["first sensor roll, pitch, yaw (deg)", sensor_angles]]
    for k, mode in enumerate(best["modes"]):
        position, angles = position_and_angles(_se3(mode["T_world_object_wxyz_xyz"]))
        detail.append([f"mode {k + 1}: P {mode['probability']:.3f}", f"object at {position} mm, {angles} deg"])
    print(format_table(["most probable object", "value"], detail))
    _write(args, image_paths, openings, frame, names, probabilities, summaries, chosen)
    return 0


def _se3(wxyz_xyz):
    import jaxlie
    import numpy as np

    return jaxlie.SE3(np.asarray(wxyz_xyz, np.float32))


def _write(args, image_paths, openings, frame, names, probabilities, summaries, chosen) -> None:
    """The belief's answer as JSON (``tactojax view --estimates`` reads it as well)."""
    if not args.json:
        return
    best = summaries[chosen] if chosen is not None else None
    payload = {
        "method": "belief", "images": image_paths, "second_images": args.second_images, "openings_mm": openings,
        "T_world_gripper_wxyz_xyz": args.gripper_poses, "frame": frame,
        "object_id": names[chosen] if chosen is not None else None,
        "object_probabilities": dict(zip(names, probabilities.astype(float).tolist())),
        "objects": dict(zip(names, summaries))}
    if best is not None:
        payload.update(
            T_world_object_wxyz_xyz=best["T_world_object_wxyz_xyz"],
            T_object_sensor_wxyz_xyz=best["T_object_sensor_wxyz_xyz"],
            probability_within_2mm=best["probability_within_2mm"], probability=best["probability_within_2mm"],
            modes=best["modes"],
            belief=[{"T_object_sensor_wxyz_xyz": m["T_object_sensor_wxyz_xyz"], "probability": m["probability"]}
                    for m in best["modes"]])
    write_json(args.json, payload)


def _run_baseline(args, method, maps, image_path, opening, observed) -> int:
    """One touch by one of the paper's baselines: identification by the closest imprint, then the pose."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from tactojax.cli._belief import position_and_angles, wxyz_xyz
    from tactojax.localize import LocalizationMap, Touch
    from tactojax.localize.baselines import MapLibrary, identify, localize_baseline

    heightmap, mask, feature = observed
    chosen, similarities = identify(MapLibrary.from_maps(maps), feature, jnp.float32(opening))
    tactile_map = maps[int(chosen)]
    touch = Touch(heightmap=heightmap, mask=mask, feature=feature, opening=np.float32(opening))
    estimate = localize_baseline(jax.random.key(0), LocalizationMap.from_tactile_map(tactile_map), touch,
                                 method=method)
    position, angles = position_and_angles(estimate.T_object_sensor)
    print(format_table(["", "value"], [
        ["object", f"{tactile_map.object_id} (similarity {float(similarities[int(chosen)]):.3f})"],
        ["method", f"{method.name} (a one-touch baseline)"],
        ["sensor position in object frame (mm)", position],
        ["roll, pitch, yaw (deg)", angles],
        ["fit residual (mm)", float(estimate.score)],
        ["overlap", float(estimate.overlap)],
        ["converged", f"{bool(estimate.converged)} ({int(estimate.iterations)} iterations)"],
    ]))
    if args.json:
        write_json(args.json, {
            "image": image_path, "opening_mm": opening, "method": method.name, "object_id": tactile_map.object_id,
            "similarities": {m.object_id: float(s) for m, s in zip(maps, np.asarray(similarities))},
            "T_object_sensor_wxyz_xyz": wxyz_xyz(estimate.T_object_sensor),
            "score_mm": float(estimate.score), "overlap": float(estimate.overlap),
            "converged": bool(estimate.converged), "iterations": int(estimate.iterations)})
    return 0 if bool(estimate.converged) else 1
