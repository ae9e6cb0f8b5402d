"""``tactojax calibrate FRAMES --ball-radius-mm R --out CALIB``: fit a real sensor from ball presses."""

from __future__ import annotations

import time
from pathlib import Path

from tactojax.cli._table import format_table, write_json

COLUMNS = [
    ("press", "press", None),
    ("contact_radius_mm", "contact r mm", 1.0),
    ("ideal_depth_mm", "ideal depth mm", 1.0),
    ("depth_mm", "depth mm", 1.0),
    ("fitted_radius_mm", "fitted R mm", 1.0),
    ("fitted_radius_error", "R error %", 100.0),
    ("cap_residual_rmse_mm", "cap resid mm", 1.0),
    ("ideal_cap_rmse_mm", "vs ideal mm", 1.0),
    ("mask_iou", "IoU", 1.0),
]


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "calibrate", help="fit a real GelSight-type sensor's colour -> slope model from ball presses",
        description="Fit the classical lookup model (colour change -> slope table + Poisson integration) "
        "from annotated ball presses, report how well it reconstructs held-out presses (sphere-cap "
        "fit), and save it as a shape model.")
    parser.add_argument("frames", help="taxim:gelsight, taxim:gelsight_mini, a taxim dataPack .npz, or a directory "
                        "with background.png, press images and presses.csv "
                        "(image,center_x_px,center_y_px,radius_px)")
    parser.add_argument("--out", required=True, help="shape model file to write (.msgpack)")
    parser.add_argument("--ball-radius-mm", type=float, help="measured ball radius, mm (estimated when omitted, "
                        "which needs a near-Lambertian gel)")
    parser.add_argument("--mm-per-px", type=float,
                        help="pixel pitch of the frames, mm (required for .npz and directories)")
    parser.add_argument("--held-out-fraction", type=float, default=0.25,
                        help="fraction of presses kept out of the fit for evaluation (default 0.25: every 4th)")
    parser.add_argument("--bins", type=int, default=24, help="lookup-table bins per colour channel (default 24)")
    parser.add_argument("--json", metavar="PATH", help="also write the report as JSON")
    parser.set_defaults(run=run)


def run(args) -> int:
    from tactojax.io._presses import load_ball_presses
    from tactojax.io._shape import save_shape_model
    from tactojax.shape._calibrate import BallRadiusNotIdentifiableError, calibrate_from_presses

    if args.bins < 2:
        raise ValueError(f"--bins must be at least 2, got {args.bins}")
    presses = load_ball_presses(args.frames, mm_per_px=args.mm_per_px)
    radii = presses.contact_radii_mm
    height_px, width_px = presses.image_shape
    print(f"{args.frames}: {len(presses)} presses, {width_px} x {height_px} px at {presses.mm_per_px:g} mm/px, "
          f"contact radii {radii.min():.3f}-{radii.max():.3f} mm")
    start = time.perf_counter()
    try:
        model, report = calibrate_from_presses(presses, args.ball_radius_mm, held_out_fraction=args.held_out_fraction,
                                               bins=args.bins)
    except BallRadiusNotIdentifiableError as error:
        _print_estimate(error.table)
        raise
    seconds = time.perf_counter() - start
    if report["ball_radius_estimated"]:
        _print_estimate(report["radius_estimate"])
        print(f"ball radius estimated from the presses: {report['ball_radius_mm']:.4f} mm")
    else:
        print(f"ball radius {report['ball_radius_mm']:.4f} mm (given)")
    held_out = report["held_out"]
    print(f"\nfitted on {len(report['train_presses'])} presses, contact threshold "
          f"{report['mask_threshold_mm']:.3f} mm; held-out presses ({held_out['count']}):")
    print(format_table([title for _, title, _ in COLUMNS], _rows(held_out)))
    metadata = {"command": "calibrate", "source": str(args.frames), "ball_radius_mm": report["ball_radius_mm"],
                "ball_radius_estimated": report["ball_radius_estimated"], "report": report}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    path = save_shape_model(args.out, model, metadata=metadata)
    print(f"\nwrote lookup model ({presses.sensor or 'sensor'}, {width_px} x {height_px} px) to {path} "
          f"in {seconds:.1f} s")
    if args.json:
        write_json(args.json, {"source": str(args.frames), "model": str(path), "seconds": seconds, **report})
    return 0


def _rows(held_out: dict) -> list[list]:
    rows = [[row[key] if scale is None else row[key] * scale for key, _, scale in COLUMNS]
            for row in held_out["presses"]]
    for label in ("mean", "std"):
        rows.append([label] + [held_out[label][key] * scale for key, _, scale in COLUMNS[1:]])
    return rows


def _print_estimate(table: dict) -> None:
    print(f"ball radius estimate ({table['method']}; {table['folds']}-fold):")
    rows = [[radius, 255.0 * rmse] for radius, rmse in zip(table["ball_radius_mm"], table["colour_rmse"])]
    print(format_table(["R mm", "held-out colour RMSE /255"], rows))
    print(f"best {table['best_candidate_mm']:.3f} mm, consistency t = {table['t_statistic']:.1f}, colour explained "
          f"{100 * table['explained']:.1f} %, lower bound (largest contact radius) {table['lower_bound_mm']:.4f} mm, "
          f"identifiable: {'yes' if table['identifiable'] else 'no'}")
