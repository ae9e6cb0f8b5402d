"""``tactojax fit-shape MAP --kind KIND``: recover a Table II shape's dimensions from its map."""

from __future__ import annotations

from tactojax.cli._table import format_table, write_json

KINDS = ("cylinder", "semicone", "double-cylinder", "cuboid", "semipyramid")


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "fit-shape", help="fit a parametric shape to a tactile map (Table II)",
        description="Robust least-squares fit of a parametric shape (pose and dimensions) to the "
                    "map's contact cloud. When the map's object is in the catalog, the true "
                    "dimensions and relative errors are printed too.")
    parser.add_argument("map", help="tactile map (.npz) from `tactojax map`")
    parser.add_argument("--kind", required=True, choices=KINDS)
    parser.add_argument("--voxel-mm", type=float, default=0.5, help="downsample the cloud first, mm")
    parser.add_argument("--json", metavar="PATH", help="write the estimates as JSON")
    parser.set_defaults(run=run)


def run(args) -> int:
    import numpy as np

    from tactojax.io import load_tactile_map
    from tactojax.mapping import fit_tactile_map, shape_fit_errors, true_shape_parameters
    from tactojax.objects import CATALOG, get_object

    tactile_map = load_tactile_map(args.map)
    fit = fit_tactile_map(tactile_map, args.kind, voxel_mm=args.voxel_mm)
    estimates = {name: float(value) for name, value in fit.parameters.items()}
    truth = None
    if tactile_map.object_id in CATALOG:
        try:
            truth = true_shape_parameters(get_object(tactile_map.object_id), args.kind)
        except ValueError:  # a catalog object that is not this kind of shape
            truth = None
    errors = shape_fit_errors(fit, truth) if truth else {}

    def shown(name, value):
        return f"{np.rad2deg(value):.2f} deg" if name.endswith("_rad") else f"{value:.2f} mm"

    rows = []
    for name, value in estimates.items():
        row = [name.removesuffix("_mm").removesuffix("_rad"), shown(name, value)]
        if name in errors:
            row += [shown(name, errors[name]["true"]), f"{100 * errors[name]['relative_error']:.2f} %"]
        elif truth:
            row += ["", "(nuisance)"]
        rows.append(row)
    print(f"{args.kind} fitted to {tactile_map.object_id}: "
          f"{'converged' if bool(fit.converged) else 'DID NOT CONVERGE'} in {int(fit.iterations)} "
          f"iterations, RMS distance {float(fit.rms_residual_mm):.3f} mm, "
          f"{100 * float(fit.inlier_fraction):.0f} % inliers")
    print(format_table(["parameter", "estimate", *(["true", "relative error"] if truth else [])], rows))
    if args.json:
        write_json(args.json, {
            "map": args.map, "object_id": tactile_map.object_id, "kind": args.kind,
            "converged": bool(fit.converged), "iterations": int(fit.iterations),
            "rms_residual_mm": float(fit.rms_residual_mm), "inlier_fraction": float(fit.inlier_fraction),
            "estimates": estimates, "errors": errors,
            "T_object_shape": np.asarray(fit.T_object_shape.wxyz_xyz).tolist()})
    return 0 if bool(fit.converged) else 1
