"""``tactojax demo``: an end-to-end run on built-in objects.

Simulate the mapping protocol on a few objects (paper section V), print a table, and save a
figure of tactile images, heightmaps and the stitched ground-truth contact clouds; then recover
every imprint's heightmap from its image with the bundled ``fast`` shape model (section IV),
which never saw these objects, and report its error with a figure.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import jax

from tactojax.cli._table import format_table, write_json

DEMO_OBJECTS = ("cylinder", "gum_box", "scissors")


def add_parser(commands) -> None:
    parser = commands.add_parser("demo", help="end-to-end run on built-in objects",
                                 description="Simulate the mapping protocol on built-in objects and save a figure.")
    parser.add_argument("--out", default="tactojax-demo", help="output folder (default ./tactojax-demo)")
    parser.add_argument("--objects", nargs="+", default=list(DEMO_OBJECTS))
    parser.add_argument("--grid-mm", type=float, default=15.0, help="mapping grid, mm (default 15 for speed)")
    parser.add_argument("--scale", type=float, default=0.5, help="sensor resolution factor (default 0.5)")
    parser.add_argument("--json", metavar="PATH", help="also write the table as JSON")
    parser.add_argument("--seed", type=int, default=0)
    parser.set_defaults(run=run)


def run(args) -> int:
    from tactojax.io import open_dataset, simulate_to_dataset
    from tactojax.objects import get_object
    from tactojax.sensor import gelslim
    from tactojax.simulate import MappingProtocol, mapping_plan
    from tactojax.viz import imprint_figure

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    spec = gelslim(scale=args.scale)
    protocol = MappingProtocol(grid_mm=args.grid_mm)
    rows, per_object = [], {}
    for index, name in enumerate(args.objects):
        try:
            obj = get_object(name)
        except ImportError as error:
            print(f"skipping {name}: {error}")
            continue
        dataset = out / "datasets" / name
        shutil.rmtree(dataset, ignore_errors=True)  # the demo starts each object afresh
        start = time.perf_counter()
        count = simulate_to_dataset(dataset, jax.random.key(args.seed + index), spec, obj, protocol)
        seconds = time.perf_counter() - start
        records = open_dataset(dataset).read()
        per_object[name] = records
        area = records["mask"].sum(axis=(1, 2)) * spec.mm_per_px**2
        rows.append([name, len(mapping_plan(obj, protocol)), count, float(area.mean()) if count else 0.0,
                     float(records["opening_mm"].mean()) if count else 0.0, seconds])
    headers = ["object", "grasps planned", "imprints", "mean contact (mm^2)", "mean opening (mm)", "time (s)"]
    print(format_table(headers, rows))
    figure = imprint_figure(per_object, spec.mm_per_px, out / "demo_imprints.png")
    print(f"figure: {figure}")
    report = {"rows": [dict(zip(headers, row)) for row in rows], "figure": str(figure)}
    report["local_shape"] = _local_shape(per_object, spec, out)
    if args.json:
        write_json(args.json, report)
    return 0


def _local_shape(per_object: dict, spec, out: Path) -> dict | None:
    """Heightmaps from images with the bundled model, against the simulator's ground truth."""
    import numpy as np

    from tactojax.cli._shape_report import print_shape_report
    from tactojax.io import bundled_shape_models, resolve_shape_model
    from tactojax.shape import ShapeData, evaluate_shape_model, predict_batch
    from tactojax.viz import shape_examples_figure

    name = f"fast-{spec.name}-{spec.height_px / 240:g}"
    if name not in bundled_shape_models():
        print(f"no bundled shape model for {spec.name} at {spec.height_px}x{spec.width_px} px; "
              f"skipping local shape (bundled: {bundled_shape_models()})")
        return None
    model = resolve_shape_model(f"bundled:{name}")
    records = [r for r in per_object.values() if len(r["image"])]
    data = ShapeData(images=np.concatenate([r["image"] for r in records]),
                     heightmaps=np.concatenate([r["heightmap"] for r in records]),
                     masks=np.concatenate([r["mask"] for r in records]),
                     object_ids=np.concatenate([r["object_id"] for r in records]).astype(str),
                     mm_per_px=spec.mm_per_px, sensor=spec.name)
    errors = evaluate_shape_model(model, data, progress=True)
    summary = print_shape_report(errors, data.object_ids,
                                 title=f"local shape: image -> heightmap with bundled:{name} (unseen objects)")
    # One imprint per object: the one with the median contact area.
    rows = []
    for name in dict.fromkeys(data.object_ids.tolist()):
        members = np.flatnonzero(data.object_ids == name)
        areas = data.masks[members].sum(axis=(1, 2))
        rows.append(int(members[np.argsort(areas)[len(areas) // 2]]))
    padded = rows + [rows[-1]] * (32 - len(rows))  # reuse the evaluation's compiled batch size
    predicted = np.asarray(predict_batch(model, data.images_float(padded))[0])[: len(rows)]
    figure = shape_examples_figure(data.images[rows], data.heightmaps[rows], predicted,
                                   out / "demo_local_shape.png", mm_per_px=spec.mm_per_px,
                                   titles=[str(data.object_ids[r]) for r in rows])
    print(f"figure: {figure}")
    return {"model": f"bundled:{name}", "errors": summary, "figure": str(figure)}
