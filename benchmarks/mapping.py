"""Global tactile maps (paper section V): Table II shape recovery, map quality, grid, noise.

What is measured, on the simulated Table II shapes (gelslim at half resolution, the mapping
protocol: grasps on a grid in the plane of the gripper, yaws 0 / +-20 deg, the object turned
0 / 90 / 180 / 270 deg), with maps built from heightmaps *predicted* by the shape model:

1. Table II: every shape's parameters fitted to its map (10 mm grid), estimate, true value and
   relative error, beside the paper's (every parameter within 5.5 %; our target 1 %). The fit
   uses the map's contact pixels less the membrane skirt, and depth only where the sensor
   observed it (``tactojax.mapping.shape_fit_clouds``); ``--plain-fit`` fits the map's own
   points instead.
2. Map quality: distance of the map's points to the true surface (mm), and how it and the fits
   change with the grid spacing (5 / 10 / 20 mm).
3. Kinematic noise: the 10 mm maps rebuilt with the recorded gripper poses and openings
   perturbed (``tactojax.mapping.NOISE_LEVELS``: low, realistic, high), fits and quality again.

Run from the repository root (data is simulated into --work once and reused, shared with the
other benchmarks):

    python benchmarks/mapping.py --json results/mapping.json --figures results/maps
    python benchmarks/mapping.py --quick          # smoke run: 20 mm grid, two shapes
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import jax
import numpy as np

try:
    from benchmarks._common import (DEFAULT_MODEL, WORK, add_common_arguments, format_table, machine_info, simulated,
                                    write_json)
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from _common import DEFAULT_MODEL, WORK, add_common_arguments, format_table, machine_info, simulated, write_json

from tactojax.io import read_grasps, resolve_shape_model
from tactojax.mapping import (NOISE_LEVELS, build_tactile_map, fit_shape_to_clouds, perturb_kinematics,
                              shape_fit_clouds, shape_fit_errors, stitched_point_cloud, surface_distance,
                              true_shape_parameters)
from tactojax.objects import TABLE2_SHAPES, get_object
from tactojax.simulate import MappingProtocol

SHAPE_KIND = {"cylinder": "cylinder", "semicone": "semicone", "double_cylinder": "double-cylinder",
              "cuboid": "cuboid", "semipyramid": "semipyramid"}
PAPER_TABLE2 = {  # (shape, parameter): (paper's estimate, paper's relative error %)
    ("cylinder", "radius_mm"): (24.8, 2.9),
    ("semicone", "base_radius_mm"): (19.8, 2.2), ("semicone", "slope_rad"): (np.deg2rad(7.5), 0.1),
    ("double_cylinder", "big_radius_mm"): (15.3, 4.4), ("double_cylinder", "small_radius_mm"): (10.4, 5.5),
    ("double_cylinder", "joint_mm"): (61.9, 3.2),
    ("cuboid", "side_1_mm"): (26.0, 4.0), ("cuboid", "side_2_mm"): (20.9, 4.5),
    ("semipyramid", "base_side_mm"): (19.7, 1.5), ("semipyramid", "slope_rad"): (np.deg2rad(7.2), 4.0),
}


def simulate_mapping(work, name: str, grid_mm: float, scale: float, seed: int) -> Path:
    """The mapping protocol on one object, simulated once into ``work`` (shared with the other benchmarks)."""
    return simulated(work, name, MappingProtocol(grid_mm=grid_mm), f"map-grid{grid_mm:g}", seed=seed, scale=scale)


def map_and_fit(model, path: Path, name: str, *, noise: str = "none", seed: int = 0, refine_contact: bool = True):
    """Build the map (optionally with kinematic noise), fit the shape, measure the map."""
    grasps = read_grasps(path)
    T_world_gripper, openings = grasps["T_world_gripper"], grasps["openings"]
    if noise != "none":
        T_world_gripper, openings = perturb_kinematics(jax.random.key(seed), T_world_gripper, openings,
                                                       NOISE_LEVELS[noise])
    start = time.perf_counter()
    tactile_map = build_tactile_map(model, grasps["images"], T_world_gripper, openings, name,
                                    T_world_object=grasps["T_world_object"], progress=False)
    build_s = time.perf_counter() - start
    start = time.perf_counter()  # the clouds once: fitted, then measured against the surface
    depth_points, contact_points = shape_fit_clouds(tactile_map, refine_contact=refine_contact)
    fit = fit_shape_to_clouds(depth_points, contact_points, SHAPE_KIND[name])
    fit_s = time.perf_counter() - start
    obj = get_object(name)
    points, _ = stitched_point_cloud(tactile_map)
    errors = shape_fit_errors(fit, true_shape_parameters(obj, SHAPE_KIND[name]))
    result = {
        "imprints": len(tactile_map), "with_contact": int(tactile_map.imprint_valid.sum()),
        "points": int(len(points)), "build_s": build_s, "fit_s": fit_s,
        "converged": bool(fit.converged), "fit_rms_residual_mm": float(fit.rms_residual_mm),
        "parameters": errors, "max_relative_error": max(abs(e["relative_error"]) for e in errors.values()),
        "surface_distance_mm": surface_distance(obj, points),
        "fit_cloud_surface_distance_mm": {"depth": surface_distance(obj, depth_points),
                                          "contact": surface_distance(obj, contact_points)},
    }
    return tactile_map, result


def _percent(x: float) -> str:
    return f"{100 * x:.2f} %"


def _value(name: str, x: float) -> str:
    return f"{np.rad2deg(x):.2f} deg" if name.endswith("_rad") else f"{x:.2f}"


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--work", default=WORK, help=f"simulated data cache (default {WORK})")
    parser.add_argument("--model", default=DEFAULT_MODEL, help="shape model")
    parser.add_argument("--scale", type=float, default=0.5, help="gelslim resolution factor (the model's)")
    parser.add_argument("--grids", default="5,10,20", help="grid spacings for the map-quality study, mm")
    parser.add_argument("--noise", default="low,realistic,high", help="kinematic noise levels ('' to skip)")
    parser.add_argument("--shapes", default=",".join(TABLE2_SHAPES))
    parser.add_argument("--figures", metavar="DIR", help="save a figure of every 10 mm map here")
    parser.add_argument("--plain-fit", action="store_true",
                        help="fit the map's own points (no skirt removal, depth everywhere)")
    add_common_arguments(parser, quick="20 mm grid, two shapes, one noise level",
                         seed_help="simulated data and kinematic noise")
    args = parser.parse_args()
    args.shapes = args.shapes.split(",") if not args.quick else ["cylinder", "cuboid"]
    args.grids = [float(g) for g in args.grids.split(",")] if not args.quick else [20.0]
    args.noise = [n for n in args.noise.split(",") if n] if not args.quick else ["realistic"]
    return args


def grid_study(args, model, results: dict, save) -> None:
    """Every shape mapped and fitted at every grid spacing (a figure of the Table II maps)."""
    for grid in args.grids:
        results["grids"][grid] = {}
        for name in args.shapes:
            tactile_map, result = map_and_fit(model, simulate_mapping(args.work, name, grid, args.scale, args.seed),
                                              name, refine_contact=not args.plain_fit)
            results["grids"][grid][name] = result
            print(f"grid {grid:g} mm, {name}: {result['with_contact']} imprints, max error "
                  f"{_percent(result['max_relative_error'])}, map points "
                  f"{result['surface_distance_mm']['mean']:.3f} mm from the surface (fitted depth points "
                  f"{result['fit_cloud_surface_distance_mm']['depth']['mean']:.3f} mm)", flush=True)
            if args.figures and grid == args.table_grid:
                from tactojax.viz import tactile_map_figure

                points, _ = stitched_point_cloud(tactile_map)
                tactile_map_figure(points, Path(args.figures) / f"{name}.png",
                                   title=f"{name}: {result['with_contact']} imprints, grid {grid:g} mm")
            save()


def print_grid_study(args, results: dict) -> None:
    rows = []
    for name in args.shapes:
        for parameter, error in results["grids"][args.table_grid][name]["parameters"].items():
            paper = PAPER_TABLE2.get((name, parameter), (float("nan"), float("nan")))
            rows.append([name, parameter, _value(parameter, error["true"]), _value(parameter, error["estimate"]),
                         _percent(abs(error["relative_error"])), _value(parameter, paper[0]), f"{paper[1]} %"])
    print(f"\nTable II: parameters fitted to the tactile maps ({args.table_grid:g} mm grid); paper: every "
          "parameter within 5.5 %")
    print(format_table(["shape", "parameter", "true", "estimate", "error", "paper estimate", "paper error"], rows))
    print("\nMap quality against the grid spacing: mean distance of map points to the true surface "
          "(mm) / worst parameter error")
    print(format_table(["shape", *[f"grid {g:g} mm" for g in args.grids]],
                       [[name, *[f"{results['grids'][g][name]['surface_distance_mm']['mean']:.3f} / "
                                 f"{_percent(results['grids'][g][name]['max_relative_error'])}" for g in args.grids]]
                        for name in args.shapes]))


def noise_study(args, model, results: dict, save) -> None:
    """The Table II grid's maps rebuilt with perturbed kinematics, fitted and measured again."""
    for level in args.noise:
        results["noise"][level] = {"model": dataclasses.asdict(NOISE_LEVELS[level])}
        for name in args.shapes:
            path = simulate_mapping(args.work, name, args.table_grid, args.scale, args.seed)
            _, result = map_and_fit(model, path, name, noise=level, seed=args.seed, refine_contact=not args.plain_fit)
            results["noise"][level][name] = result
        save()


def print_noise_study(args, results: dict) -> None:
    clean = results["grids"][args.table_grid]
    levels = ["none", *args.noise]
    print(f"\nKinematic noise ({args.table_grid:g} mm grid): worst parameter error / mean distance to the surface (mm)")
    for level in args.noise:
        noise = NOISE_LEVELS[level]
        print(f"  {level}: gripper position sigma {noise.translation_mm} mm, orientation sigma "
              f"{noise.rotation_deg} deg, opening sigma {noise.opening_mm} mm per grasp")

    def cell(level, name):
        entry = (clean if level == "none" else results["noise"][level])[name]
        return f"{_percent(entry['max_relative_error'])} / {entry['surface_distance_mm']['mean']:.3f}"

    print(format_table(["shape", *levels], [[name, *[cell(level, name) for level in levels]] for name in args.shapes]))


def main() -> None:
    args = parse_args()
    args.table_grid = 10.0 if 10.0 in args.grids else args.grids[0]
    model = resolve_shape_model(args.model)
    results: dict = {"machine": machine_info(), "settings": dict(vars(args)), "grids": {}, "noise": {}}

    def save():  # after every section, so an interrupted run keeps what it measured
        if args.json:
            write_json(args.json, results)

    grid_study(args, model, results, save)
    print_grid_study(args, results)
    save()
    noise_study(args, model, results, save)
    if args.noise:
        print_noise_study(args, results)
    save()
    if args.json:
        print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
