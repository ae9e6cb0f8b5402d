"""``tactojax map-catalog OBJECT... --out DIR``: simulate and map many objects into one catalog."""

from __future__ import annotations

import shutil
import sys
import time
import warnings
from pathlib import Path

from tactojax.cli._map import DEFAULT_MODEL
from tactojax.cli._simulate import DEFAULT_SCALE
from tactojax.cli._table import format_table

DATA_FOLDER = ".data"
"""Inside the catalog: one object's simulated mapping dataset while its map is built."""
UNCALIBRATED = {"calibrate": 0, "calibration_turns_deg": [0.0, 180.0]}
"""The calibration settings of a catalog built before ``--calibrate`` existed."""


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "map-catalog", help="simulate and map many objects into a catalog directory (resumable)",
        description="For every object: simulate the paper's mapping protocol, build its tactile map with "
                    "MODEL (predicted heightmaps), store the retrieval features of ENCODER (the images are "
                    "dropped unless --keep-images), and list it in DIR/catalog.json. An object already built "
                    "is skipped, so an interrupted run goes on where it stopped; an object that cannot be "
                    "mapped (the gripper cannot grasp it, its mesh does not load) is listed with the reason "
                    "and the others go on. identify, localize, localize-live and eval-localization take DIR "
                    "where they take maps. Objects are built one after the other: each stage already uses "
                    "every core.")
    parser.add_argument("objects", nargs="+", metavar="OBJECT",
                        help="catalog names, ycb:ID, ycb:all (every YCB scan), ycb:training (those the "
                             "encoder may see) or mesh paths")
    parser.add_argument("--out", required=True, metavar="DIR", help="catalog directory (created, or resumed)")
    parser.add_argument("--mesh-units", choices=["m", "cm", "mm"], default="m", help="length unit of mesh files")
    parser.add_argument("--grid-mm", type=float, default=10.0, help="mapping grid spacing, mm (default 10)")
    parser.add_argument("--max-grasps", type=int, default=None,
                        help="widen an object's grid (0.5 mm steps) until its plan has at most this many grasps "
                             "(bounds the time and size of large objects)")
    parser.add_argument("--scale", type=float, default=DEFAULT_SCALE, help=f"gelslim resolution factor (default "
                                                                            f"{DEFAULT_SCALE}, the bundled model's)")
    parser.add_argument("--model", default=DEFAULT_MODEL, help=f"shape model (default {DEFAULT_MODEL})")
    parser.add_argument("--encoder", default=None,
                        help="feature encoder stored with the maps (default: the bundled one)")
    parser.add_argument("--points", type=int, default=1024, help="contact points kept per imprint")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--calibrate", type=int, default=0, metavar="EPISODES",
                        help="also simulate this many episodes of 3 two-finger grasps of each object (a key of their "
                             "own, off the mapping grid) and fit how often the belief's search misses the true pose's "
                             "mode, stored in the map's header as `calibrate-belief --search-only` does (every scale "
                             "for another encoder's features); 64 is enough for a stable fit, about 40 s per object "
                             "on 2 cores. Default 0: the default calibration, fit on the five catalog objects pooled, "
                             "which is overconfident on a single touch of a flat face")
    parser.add_argument("--calibration-turns-deg", type=float, nargs="+", default=[0.0, 180.0], metavar="DEG",
                        help="object turns the calibration episodes draw from (default 0 180: as the new-grasps "
                             "benchmark; give those the robot will meet)")
    parser.add_argument("--keep-images", action="store_true",
                        help="keep the tactile images in the maps (features from another encoder need them)")
    parser.add_argument("--keep-data", action="store_true", help="keep each object's simulated dataset "
                                                                 f"(under DIR/{DATA_FOLDER})")
    parser.add_argument("--no-progress", action="store_true")
    parser.set_defaults(run=run)


def expand_objects(names: list[str]) -> list[str]:
    """The objects asked for, with ``ycb:all`` and ``ycb:training`` spelt out, each once, in order.

    A YCB scan that a catalog object is (``ycb:037_scissors`` is ``scissors``,
    :data:`~tactojax.objects.CATALOG_YCB_SCANS`) goes by the catalog's name, which declares its
    symmetry: a catalog never holds one object twice, which no touch could tell apart."""
    from tactojax.objects import CATALOG_YCB_SCANS, ycb_scans

    catalog_name = {f"ycb:{scan}": name for name, scan in CATALOG_YCB_SCANS.items()}
    out: list[str] = []
    for name in names:
        if name in ("ycb:all", "ycb:training"):
            out.extend(f"ycb:{scan}" for scan in ycb_scans(training=name == "ycb:training"))
        else:
            out.append(name)
    return list(dict.fromkeys(catalog_name.get(name, name) for name in out))


def run(args) -> int:
    from tqdm.auto import tqdm

    from tactojax.io import (DEFAULT_ENCODER, encoder_label, read_catalog, resolve_encoder, resolve_shape_model,
                             write_catalog)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    objects = expand_objects(args.objects)
    settings = {"grid_mm": args.grid_mm, "max_grasps": args.max_grasps, "scale": args.scale, "model": args.model,
                "encoder": encoder_label(args.encoder or DEFAULT_ENCODER), "points": args.points, "seed": args.seed,
                "calibrate": args.calibrate, "calibration_turns_deg": [float(t) for t in args.calibration_turns_deg]}
    if args.calibrate < 0:
        raise ValueError(f"--calibrate takes a number of episodes (0: none), got {args.calibrate}")
    index = read_catalog(out)
    if index["objects"] and {**UNCALIBRATED, **index["settings"]} != settings:
        raise ValueError(f"{out} was built with other settings ({index['settings']}); use another --out to "
                         "build a catalog with these")
    index["settings"] = settings
    model, encoder = resolve_shape_model(args.model), resolve_encoder(settings["encoder"])
    todo = [name for name in objects if index["objects"].get(name, {}).get("status") != "built"]
    if len(todo) < len(objects):
        print(f"{len(objects) - len(todo)} of {len(objects)} objects already built in {out}: going on")
    bar = tqdm(todo, desc="objects", unit="object", disable=args.no_progress)
    for name in bar:
        bar.set_postfix_str(name)
        start = time.perf_counter()
        try:
            entry = _build_object(name, out, model, encoder, settings["encoder"], args)
        except (ValueError, FileNotFoundError, ImportError, RuntimeError) as error:
            entry = {"status": "failed", "error": str(error)}
            print(f"{name}: not mapped: {error}", file=sys.stderr)
        entry["seconds"] = round(time.perf_counter() - start, 1)
        index["objects"][name] = entry
        write_catalog(out, index)  # after every object: an interruption loses at most the one in progress
    print(summary_table(out, index))
    return 0 if any(e["status"] == "built" for e in index["objects"].values()) else 1


def _build_object(name: str, out: Path, model, encoder, encoder_name: str, args) -> dict:
    """Simulate, map and save one object; its dataset is removed afterwards (unless --keep-data)."""
    import dataclasses

    import jax

    from tactojax.features import encode_images
    from tactojax.io import MeshRepairedWarning, catalog_slug, read_grasps, save_tactile_map
    from tactojax.mapping import build_tactile_map
    from tactojax.objects import resolve_object
    from tactojax.sensor import sensor_preset
    from tactojax.simulate import MappingProtocol, mapping_grid_for, simulate_to_dataset

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MeshRepairedWarning)
        obj = resolve_object(name, units=args.mesh_units)
    protocol = MappingProtocol(grid_mm=args.grid_mm)
    if args.max_grasps is not None:
        protocol = dataclasses.replace(protocol, grid_mm=mapping_grid_for(obj, protocol, args.max_grasps))
    spec = sensor_preset("gelslim", scale=args.scale)
    if abs(spec.mm_per_px - model.mm_per_px) > 1e-6:
        raise ValueError(f"the shape model reads {model.mm_per_px} mm/px, gelslim at --scale {args.scale} gives "
                         f"{spec.mm_per_px}: pass the model for this scale")
    slug = catalog_slug(name)
    data = out / DATA_FOLDER / slug
    shutil.rmtree(data, ignore_errors=True)  # a dataset left by an interrupted run is not trusted
    progress = not args.no_progress
    simulate_to_dataset(data, jax.random.key(args.seed), spec, obj, protocol, progress=progress)
    grasps = read_grasps(data)
    tactile_map = build_tactile_map(model, grasps["images"], grasps["T_world_gripper"], grasps["openings"],
                                    grasps["object_id"], T_world_object=grasps["T_world_object"],
                                    points_per_imprint=args.points, key=jax.random.key(args.seed), progress=progress)
    tactile_map = tactile_map.with_features(encode_images(encoder, tactile_map.images, progress=progress))
    tactile_map = tactile_map.replace(symmetry=obj.symmetry)
    if not args.keep_images:  # the features are stored: localization needs the images no more
        tactile_map = tactile_map.replace(images=None)
    path = save_tactile_map(out / f"{slug}.npz", tactile_map, metadata={
        "data": f"{name} (mapping protocol, grid {protocol.grid_mm:g} mm)", "model": args.model,
        "features_encoder": encoder_name, "seed": args.seed})
    calibration = None
    if args.calibrate:
        calibration = _calibrate(path, tactile_map, obj, spec, model, encoder, encoder_name,
                                 data.with_name(f"{slug}-calibration"), args)
    if not args.keep_data:
        shutil.rmtree(data)
    entry = {"status": "built", "map": path.name, "object_id": tactile_map.object_id, "grid_mm": protocol.grid_mm,
             "imprints": len(tactile_map), "with_contact": int(tactile_map.imprint_valid.sum()),
             "bytes": path.stat().st_size, "symmetry": obj.symmetry.describe()}
    return entry if calibration is None else {**entry, "calibration": calibration}


def _calibrate(path: Path, tactile_map, obj, spec, model, encoder, encoder_name: str, data: Path, args) -> dict:
    """Simulate calibration episodes of the map's object and fit the belief's calibration into the map's header.

    With the default encoder's features only the missed-search term is fit (``calibrate-belief
    --search-only``: the default's scales belong to those features); with another encoder's, every
    scale (``calibrate-belief``'s rule)."""
    import jax

    from tactojax.cli._calibrate_belief import calibrate_map_file, store_calibration, typical_touch_found
    from tactojax.io import DEFAULT_ENCODER, encoder_label
    from tactojax.localize import calibration_to_json
    from tactojax.localize.evaluation import load_test_episodes
    from tactojax.simulate import GraspsProtocol, simulate_to_dataset

    protocol = GraspsProtocol(episodes=args.calibrate, grasps_per_episode=3, fingers=2,
                              turns_deg=tuple(args.calibration_turns_deg))
    shutil.rmtree(data, ignore_errors=True)
    progress = not args.no_progress
    # A key of their own: the mapping run draws from key(seed), the calibration grasps from its fold.
    simulate_to_dataset(data, jax.random.fold_in(jax.random.key(args.seed), 1), spec, obj, protocol,
                        progress=progress)
    episodes, _ = load_test_episodes(data, tactile_map.object_id, model, encoder, progress=progress)
    fit_shape = encoder_name != encoder_label(DEFAULT_ENCODER)
    calibration, report = calibrate_map_file(path, tactile_map, episodes, fit_shape=fit_shape,
                                             search_only=not fit_shape, rounds=2 if fit_shape else 1, progress=progress)
    report.update(encoder=encoder_name, grasps=f"map-catalog --calibrate {args.calibrate} (seed {args.seed}, fold 1)")
    store_calibration(path, report)
    if not args.keep_data:
        shutil.rmtree(data)
    typical, found = typical_touch_found(calibration, report)
    return {"episodes": args.calibrate, "contact_mm2": typical, "found_after_1_touch": round(found, 3),
            **calibration_to_json(calibration)}


def summary_table(path, index: dict) -> str:
    """The catalog as a table (one row per object) and its totals."""
    rows, built = [], [e for e in index["objects"].values() if e["status"] == "built"]
    for name, entry in index["objects"].items():
        if entry["status"] == "built":
            found = entry.get("calibration", {}).get("found_after_1_touch")
            rows.append([name, "built", entry["imprints"], entry["with_contact"], f"{entry['grid_mm']:g}",
                         entry["bytes"] / 1e6, entry.get("seconds"), entry.get("symmetry", "-"),
                         "default" if found is None else found])
        else:
            rows.append([name, f"failed: {entry['error'][:60]}", None, None, None, None, entry.get("seconds"), None,
                         None])
    table = format_table(["object", "status", "imprints", "with contact", "grid (mm)", "MB", "build (s)", "symmetry",
                          "P(search found), 1 touch"], rows)
    total_mb = sum(e["bytes"] for e in built) / 1e6
    total_s = sum(e.get("seconds") or 0.0 for e in index["objects"].values())
    return (f"{table}\ncatalog {path}: {len(built)} of {len(index['objects'])} objects mapped, "
            f"{total_mb:.1f} MB, built in {total_s / 60:.1f} min")
