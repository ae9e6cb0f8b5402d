"""``tactojax map DATA --model MODEL --out MAP``: stitch one object's imprints into its map."""

from __future__ import annotations

from tactojax.cli._table import format_table

DEFAULT_MODEL = "bundled:fast-gelslim-0.5"


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "map", help="build an object's tactile map from a grasp dataset",
        description="Predict every imprint's heightmap with MODEL (never the simulator's ground "
                    "truth), place it by the gripper kinematics and save the tactile map "
                    "(paper section V).")
    parser.add_argument("data", help="dataset directory (mapping protocol or a recording)")
    parser.add_argument("--model", default=DEFAULT_MODEL, help=f"shape model (default {DEFAULT_MODEL})")
    parser.add_argument("--out", required=True, help="tactile map to write (.npz)")
    parser.add_argument("--object", help="which object, when the dataset holds several")
    parser.add_argument("--symmetry", metavar="SPEC",
                        help="the object's symmetry group, stored in the map: 'none', an axis continuous or n-fold "
                             "('x', 'z2') and an optional ',flip=AXIS', in the map (object) frame (default: what "
                             "the data recorded, else the catalog's by object id)")
    parser.add_argument("--points", type=int, default=1024, help="contact points kept per imprint")
    parser.add_argument("--encoder", default=None,
                        help="encoder of the retrieval features stored with the map (bundled:NAME or a checkpoint "
                             "path; default: the bundled one); the commands that read the map then encode new "
                             "touches with it")
    parser.add_argument("--kinematic-noise", default="none", metavar="LEVEL",
                        help="perturb the recorded gripper poses and openings: none, low, "
                             "realistic or high (see tactojax.mapping.NOISE_LEVELS)")
    parser.add_argument("--ply", metavar="PATH", help="also export the stitched point cloud")
    parser.add_argument("--voxel-mm", type=float, default=0.5, help="PLY voxel size, mm")
    parser.add_argument("--keep-images", action="store_true",
                        help="keep the tactile images in the map (about 58 kB per imprint; needed only to encode "
                             "features with another encoder later)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-progress", action="store_true")
    parser.set_defaults(run=run)


def run(args) -> int:
    import jax

    from tactojax.features import encode_images
    from tactojax.io import (DEFAULT_ENCODER, encoder_label, export_ply, read_grasps, resolve_encoder, resolve_shape_model,
                             save_tactile_map)
    from tactojax.mapping import NOISE_LEVELS, build_tactile_map, perturb_kinematics
    from tactojax.objects import ObjectSymmetry

    if args.kinematic_noise not in NOISE_LEVELS:
        raise ValueError(f"unknown kinematic noise level {args.kinematic_noise!r}; choose from {sorted(NOISE_LEVELS)}")
    if args.points < 1:
        raise ValueError(f"--points must be positive, got {args.points}")
    declared = None if args.symmetry is None else ObjectSymmetry.parse(args.symmetry)  # a bad spec fails first
    model = resolve_shape_model(args.model)
    grasps = read_grasps(args.data, object_id=args.object)
    if abs(grasps["mm_per_px"] - model.mm_per_px) > 1e-6:
        raise ValueError(f"the dataset's pixel pitch ({grasps['mm_per_px']} mm) is not the shape model's "
                         f"({model.mm_per_px} mm): train or choose a model for this sensor (the bundled model "
                         "reads gelslim at `tactojax simulate --scale 0.5`, the default)")
    noise_key, sample_key = jax.random.split(jax.random.key(args.seed))
    T_world_gripper, openings = grasps["T_world_gripper"], grasps["openings"]
    if args.kinematic_noise != "none":
        T_world_gripper, openings = perturb_kinematics(noise_key, T_world_gripper, openings,
                                                       NOISE_LEVELS[args.kinematic_noise])
    tactile_map = build_tactile_map(model, grasps["images"], T_world_gripper, openings, grasps["object_id"],
                                    T_world_object=grasps["T_world_object"], points_per_imprint=args.points,
                                    key=sample_key, progress=not args.no_progress)
    # The retrieval features, once, from the images (a compact map keeps no images).
    encoder_name = encoder_label(args.encoder or DEFAULT_ENCODER)
    features = encode_images(resolve_encoder(encoder_name), tactile_map.stored_images(), progress=not args.no_progress)
    tactile_map = tactile_map.with_features(features).replace(
        symmetry=declared if declared is not None else grasps["symmetry"])
    if not args.keep_images:
        tactile_map = tactile_map.replace(images=None)
    metadata = {"data": args.data, "model": args.model, "kinematic_noise": args.kinematic_noise,
                "seed": args.seed, "features_encoder": encoder_name}
    save_tactile_map(args.out, tactile_map, metadata=metadata)
    rows = [["object", tactile_map.object_id], ["imprints", len(tactile_map)],
            ["with contact", int(tactile_map.imprint_valid.sum())],
            ["contact points", int(tactile_map.point_valid.sum())],
            ["kinematic noise", args.kinematic_noise]]
    quality = _surface_quality(tactile_map)
    if quality:
        rows.append(["distance to true surface (mm)",
                     f"mean {quality['mean']:.3f}, median {quality['median']:.3f}, p95 {quality['p95']:.3f}"])
    print(format_table(["map", str(args.out)], rows))
    if args.ply:
        count = export_ply(args.ply, tactile_map, voxel_mm=args.voxel_mm)
        print(f"point cloud: {args.ply} ({count} points, {args.voxel_mm} mm voxels)")
    return 0


def _surface_quality(tactile_map) -> dict | None:
    """Map points against the true surface, when the object is in the catalog."""
    from tactojax.mapping import stitched_point_cloud, surface_distance
    from tactojax.objects import CATALOG, get_object

    if tactile_map.object_id not in CATALOG:
        return None
    points, _ = stitched_point_cloud(tactile_map)
    return surface_distance(get_object(tactile_map.object_id), points) if len(points) else None
