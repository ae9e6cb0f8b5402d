"""``tactojax simulate OBJECT --out DIR``: simulate an exploration protocol to a dataset."""

from __future__ import annotations

import dataclasses
import shutil
import time
import warnings
from pathlib import Path

import jax

DEFAULT_SCALE = 0.5
"""The default resolution factor, as in ``tactojax record`` and ``tactojax demo``: the bundled shape
model (``bundled:fast-gelslim-0.5``) reads gelslim images at this resolution."""


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "simulate", help="simulate a mapping, calibration, new-grasps or slip protocol on an object",
        description="Simulate the paper's mapping (section V) or calibration (section IV) "
        "protocol, new grasps off the mapping grid (a localization test set) or slip sequences "
        "(the object sliding and turning in a grasp, a tracking test set), on a catalog "
        "object or a mesh file, appending imprints to a dataset.")
    parser.add_argument("object", help="catalog name (see `tactojax info --objects`), ycb:ID (`tactojax info --ycb all`) "
                                       "or mesh path (STL/OBJ/PLY)")
    parser.add_argument("--out", required=True, help="dataset directory (created, or appended to)")
    parser.add_argument("--mesh-units", choices=["m", "cm", "mm"], default="m", help="length unit of a mesh file (default m, as YCB)")
    parser.add_argument("--symmetry", metavar="SPEC",
                        help="the object's symmetry group, recorded with its touches: 'none', an axis continuous "
                             "or n-fold ('x', 'z2') and an optional ',flip=AXIS' (default: the catalog's, or "
                             "measured from a mesh)")
    parser.add_argument("--protocol", choices=["mapping", "calibration", "grasps", "slip"], default="mapping")
    parser.add_argument("--sensor", choices=["gelslim", "gelsight", "gelsight_mini"], default="gelslim")
    parser.add_argument("--scale", type=float, default=DEFAULT_SCALE,
                        help=f"sensor resolution factor in (0, 1] (default {DEFAULT_SCALE}: gelslim at 160 x 120 px, "
                             "0.2 mm/px, the bundled shape model's resolution, so that `tactojax map` reads the "
                             "dataset with its default model; 1 is full resolution)")
    parser.add_argument("--grid-mm", type=float, default=10.0, help="mapping grid spacing, mm (default 10)")
    parser.add_argument("--max-grasps", type=int, default=None,
                        help="mapping: widen the grid (0.5 mm steps) until the plan has at most this many grasps")
    parser.add_argument("--yaws-deg", type=float, nargs="+", default=[0.0, 20.0, -20.0], help="mapping yaws, degrees")
    parser.add_argument("--turns-deg", type=float, nargs="+", default=[0.0, 90.0, 180.0, 270.0], help="object turns, degrees")
    parser.add_argument("--touches", type=int, default=600, help="calibration touches per shape (default 600)")
    parser.add_argument("--episodes", type=int, default=30, help="new grasps: episodes, each one object turn (default 30)")
    parser.add_argument("--grasps-per-episode", type=int, default=5, help="new grasps per episode (default 5)")
    parser.add_argument("--fingers", type=int, choices=[1, 2], default=1, help="new grasps: sensors on 1 or both jaws")
    parser.add_argument("--yaw-range-deg", type=float, default=20.0,
                        help="new grasps and slip starts: yaw within ±this, degrees")
    parser.add_argument("--sequences", type=int, default=10, help="slip: sequences, each from a new grasp (default 10)")
    parser.add_argument("--frames", type=int, default=200, help="slip: frames per sequence (default 200)")
    parser.add_argument("--max-step-mm", type=float, default=0.5, help="slip: largest slide per frame, mm (default 0.5)")
    parser.add_argument("--max-step-deg", type=float, default=1.0,
                        help="slip: largest turn per frame about the closing axis, degrees (default 1)")
    parser.add_argument("--depth-mm", type=float, default=1.0, help="mapping penetration depth, mm (default 1)")
    parser.add_argument("--depth-noise-mm", type=float, default=0.0, help="std of the penetration depth, mm")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.set_defaults(run=run)


def run(args) -> int:
    from tactojax.io import MeshRepairedWarning
    from tactojax.objects import CATALOG, ObjectSymmetry, resolve_object
    from tactojax.sensor import sensor_preset
    from tactojax.simulate import (CalibrationProtocol, GraspConfig, GraspsProtocol, MappingProtocol, SlipProtocol,
                                   mapping_grid_for, simulate_to_dataset)

    with warnings.catch_warnings():  # said below, once, without a source line
        warnings.simplefilter("ignore", MeshRepairedWarning)
        obj = resolve_object(args.object, units=args.mesh_units)
    if obj.mesh_repair:
        print(f"{args.object}: {obj.mesh_repair['summary']}")
    if args.symmetry is not None:
        obj = dataclasses.replace(obj, symmetry=ObjectSymmetry.parse(args.symmetry))
    source = ("declared" if args.symmetry is not None else "the catalog's" if args.object in CATALOG
              else "measured from the mesh")
    print(f"{obj.name}: symmetry {obj.symmetry.describe()} ({source})")
    spec = sensor_preset(args.sensor, scale=args.scale)
    if args.protocol == "mapping":
        protocol = MappingProtocol(grid_mm=args.grid_mm, yaws_deg=tuple(args.yaws_deg), turns_deg=tuple(args.turns_deg))
        if args.max_grasps is not None:
            protocol = dataclasses.replace(protocol, grid_mm=mapping_grid_for(obj, protocol, args.max_grasps))
            print(f"{obj.name}: grid {protocol.grid_mm:g} mm (at most {args.max_grasps} grasps)")
    elif args.protocol == "grasps":
        protocol = GraspsProtocol(episodes=args.episodes, grasps_per_episode=args.grasps_per_episode,
                                  fingers=args.fingers, yaw_range_deg=args.yaw_range_deg,
                                  turns_deg=tuple(args.turns_deg))
    elif args.protocol == "slip":
        protocol = SlipProtocol(sequences=args.sequences, frames=args.frames, max_step_mm=args.max_step_mm,
                                max_step_deg=args.max_step_deg, yaw_range_deg=args.yaw_range_deg,
                                turns_deg=tuple(args.turns_deg))
    else:
        protocol = CalibrationProtocol(touches=args.touches)
    config = GraspConfig(depth_mm=args.depth_mm, depth_noise_mm=args.depth_noise_mm)
    start = time.perf_counter()
    out = Path(args.out)
    existed = out.exists()
    try:
        count = simulate_to_dataset(out, jax.random.key(args.seed), spec, obj, protocol, config=config,
                                    batch_size=args.batch_size, progress=not args.no_progress)
    except Exception:
        if not existed and not (out / "manifest.json").exists():  # nothing written: leave no empty dataset behind
            shutil.rmtree(out, ignore_errors=True)
        raise
    print(f"{obj.name}: wrote {count} imprints ({args.protocol}, {spec.name} "
          f"{spec.height_px}x{spec.width_px}) to {args.out} in {time.perf_counter() - start:.1f} s")
    if obj.attribution:
        print(f"object data: {obj.attribution}")
    return 0
