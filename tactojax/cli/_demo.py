"""``tactojax demo``: an end-to-end run on built-in objects.

For now (foundation stage): simulate the mapping protocol on a few objects, print a table, and
save a figure of tactile images, heightmaps and the stitched ground-truth contact clouds.
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
    if args.json:
        write_json(args.json, {"rows": [dict(zip(headers, row)) for row in rows], "figure": str(figure)})
    return 0
