"""``tactojax localize MAP... IMAGE --opening MM``: identify and localize one touch."""

from __future__ import annotations

from tactojax.cli._map import DEFAULT_MODEL
from tactojax.cli._maps import add_encoder_argument, maps_and_query_encoder
from tactojax.cli._table import format_table, write_json


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "localize", help="identify the object and its pose from one tactile image",
        description="Predict the touch's heightmap, compute its features, pick the object whose map "
                    "holds the most similar imprint (section VII) and register the touch against that "
                    "map (section VI). The pose is the sensor's in the object (map) frame.")
    parser.add_argument("paths", nargs="+", metavar="MAP... IMAGE",
                        help="one or more tactile maps (.npz), then the tactile image (PNG/JPEG)")
    parser.add_argument("--opening", type=float, required=True, help="gripper opening at the touch, mm")
    parser.add_argument("--method", default="cti-icp-5", help="localization method (default cti-icp-5)")
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


def run(args) -> int:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from tactojax.features import encode_image
    from tactojax.io import resolve_shape_model
    from tactojax.localize import MapLibrary, Query, identify, localize, parse_method
    from tactojax.mapping import observed_contact, shows_contact
    from tactojax.shape import check_image, predict

    if len(args.paths) < 2:
        raise ValueError("give at least one map and then the image")
    *map_paths, image_path = args.paths
    method = parse_method(args.method)
    if not np.isfinite(args.opening) or args.opening <= 0:
        raise ValueError(f"--opening must be a positive number of mm, got {args.opening}")
    model = resolve_shape_model(args.model)
    image = read_image(image_path)
    check_image(model, image)
    maps, encoder = maps_and_query_encoder(map_paths, args.encoder, progress=False)
    pixels = jnp.asarray(image, jnp.float32) / 255.0
    heightmap, mask = predict(model, pixels)
    mask = observed_contact(pixels, model.background, mask, model.mm_per_px)
    if not bool(shows_contact(pixels, model.background, mask)):
        raise ValueError(f"{image_path} shows no contact (a dark frame, or no observed pixel above the shape "
                         "model's contact threshold): no estimate")
    feature = encode_image(encoder, image)
    opening = jnp.float32(args.opening)
    chosen, similarities = identify(MapLibrary.from_maps(maps), feature, opening)
    tactile_map = maps[int(chosen)]
    query = Query(heightmap=heightmap, mask=mask, feature=feature, opening=opening)
    estimate = localize(jax.random.key(0), tactile_map, query, method=method)
    translation = np.asarray(estimate.T_object_sensor.translation())
    roll, pitch, yaw = (float(np.rad2deg(a)) for a in estimate.T_object_sensor.rotation().as_rpy_radians())
    print(format_table(["", "value"], [
        ["object", f"{tactile_map.object_id} (similarity {float(similarities[int(chosen)]):.3f})"],
        ["method", method.name],
        ["sensor position in object frame (mm)", ", ".join(f"{x:.2f}" for x in translation)],
        ["roll, pitch, yaw (deg)", f"{roll:.1f}, {pitch:.1f}, {yaw:.1f}"],
        ["fit residual (mm)", float(estimate.score)],
        ["overlap", float(estimate.overlap)],
        ["converged", f"{bool(estimate.converged)} ({int(estimate.iterations)} iterations)"],
    ]))
    if args.json:
        write_json(args.json, {
            "image": image_path, "opening_mm": args.opening, "method": method.name,
            "object_id": tactile_map.object_id,
            "similarities": {m.object_id: float(s) for m, s in zip(maps, np.asarray(similarities))},
            "T_object_sensor_wxyz_xyz": np.asarray(estimate.T_object_sensor.wxyz_xyz).tolist(),
            "score_mm": float(estimate.score), "overlap": float(estimate.overlap),
            "converged": bool(estimate.converged), "iterations": int(estimate.iterations)})
    return 0 if bool(estimate.converged) else 1
