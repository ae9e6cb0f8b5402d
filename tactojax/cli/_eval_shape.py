"""``tactojax eval-shape MODEL DATA...``: heightmap RMSE per shape and overall (Table I)."""

from __future__ import annotations

from tactojax.cli._shape_report import print_shape_report
from tactojax.cli._table import format_table, write_json


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "eval-shape", help="evaluate an image -> heightmap model on datasets",
        description="RMSE (mm) over the true contact patch and the whole image, and mask IoU, "
                    "per object and overall. MODEL is a checkpoint or bundled:NAME.")
    parser.add_argument("model", help="checkpoint (.msgpack) or bundled:NAME")
    parser.add_argument("data", nargs="+", help="dataset directories")
    parser.add_argument("--held-out", type=int, metavar="N",
                        help="evaluate only the last N pairs of every object (the split "
                             "`tactojax train --test-per-object N` held out); default all pairs")
    parser.add_argument("--robustness", action="store_true",
                        help="also evaluate under unseen lighting and extra camera noise")
    parser.add_argument("--figure", metavar="PNG", help="save image | true | predicted | error")
    parser.add_argument("--json", metavar="PATH", help="write the errors as JSON")
    parser.set_defaults(run=run)


def run(args) -> int:
    import numpy as np

    from tactojax.io import load_shape_data, resolve_shape_model
    from tactojax.shape import evaluate_shape_model, robustness_study, split_held_out

    model = resolve_shape_model(args.model)
    data = load_shape_data(args.data)
    if args.held_out:
        _, data = split_held_out(data, args.held_out)
    errors = evaluate_shape_model(model, data, progress=True)
    report = {"model": args.model, "preset": model.preset, "data": list(args.data),
              "pairs": len(data),
              "errors": print_shape_report(errors, data.object_ids, title=f"{model.preset} model")}
    if args.robustness:
        study = robustness_study(model, data)
        nominal = study["nominal"]["patch_rmse"]
        rows = [[name, f"{row['patch_rmse']:.4f}", f"{row['patch_rmse'] / nominal:.2f}x",
                 f"{row['mask_iou']:.3f}"] for name, row in study.items()]
        print("\nrobustness (all pairs): contact-patch RMSE (mm) under changes never seen in training")
        print(format_table(["condition", "patch RMSE", "vs nominal", "mask IoU"], rows))
        report["robustness"] = study
    if args.figure:
        from tactojax.shape import predict_batch
        from tactojax.viz import shape_examples_figure

        rows = [int(np.flatnonzero(data.object_ids == name)[0]) for name in data.objects][:6]
        predicted, _ = predict_batch(model, data.images_float(rows))
        shape_examples_figure(data.images[rows], data.heightmaps[rows], np.asarray(predicted),
                              args.figure, titles=[str(data.object_ids[r]) for r in rows],
                              mm_per_px=data.mm_per_px)
        print(f"figure: {args.figure}")
    if args.json:
        write_json(args.json, report)
    return 0
