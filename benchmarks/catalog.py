"""What a catalog costs against its number of maps (issue 30): memory, build, latency, identification.

For every count N of ``--counts`` (default 1, 5, 20, 50, 100; counts above the maps given are
left out), the first N maps of the catalog, as the live loop holds them:

- **memory**: the maps as the localizer holds them (one :class:`~tactojax.localize.StackedMaps`:
  each map's own imprints and surface, plus one window of padding), MB and kB per valid imprint;
- **build**: ``Localizer(maps, ...)`` wall time, with the surfaces the map files store (a map
  without one has it built then, 1-4 s a map), and its ``compile_s`` (every program compiled
  once for all maps: every map's window of the stack has one shape, so the update's program is
  the same for one map or a hundred);
- **latency**: a first grasp's update (``Localizer.fuse`` after a reset, in the foreground: every
  map's belief), a second grasp's (the same touch again: the maps still in play,
  ``LiveSettings.object_tolerance``, and how many), and a frame between updates (no contact);
  medians of ``--repeats``;
- **identification**: the paper's (section VII), every imprint held out of its own map and named
  by CTI among the N maps (``evaluate_identification``), top-1.

The reference in the same run: a localizer per map, each compiled at its map's *own* shape (no
padding: a program per map, what per-map branches cost), for counts up to ``--reference-max``.

The frame is a touch of the first map's object from a new-grasps test set (``--test DIR``, or
simulated once under ``--work``). Build the catalog first:

    tactojax map-catalog scissors tape_roll gum_box screwdriver large_marker ycb:all --out catalog
    python benchmarks/catalog.py catalog --json catalog.json
    python benchmarks/catalog.py catalog --quick       # counts 1 and 2, 3 repeats
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import numpy as np

from tactojax.io import (expand_catalogs, load_tactile_map_with_features, maps_encoder_name, read_test_grasps,
                         resolve_encoder, resolve_shape_model, stored_surface)
from tactojax.localize import Localizer
from tactojax.localize.evaluation import evaluate_identification

try:  # run as ``python benchmarks/catalog.py`` or as a module
    from benchmarks._common import (DEFAULT_MODEL, add_common_arguments, format_table, machine_info, new_grasps_set,
                                    print_machine, write_json)
except ImportError:
    from _common import (DEFAULT_MODEL, add_common_arguments, format_table, machine_info, new_grasps_set,
                         print_machine, write_json)

DEFAULT_COUNTS = "1,5,20,50,100"


def map_megabytes(stack) -> float:
    """Bytes of every array of the maps (as the live loop holds them), MB."""
    return stack.nbytes / 1e6


def median_ms(call, repeats: int) -> float:
    """Median wall time of ``call()`` over ``repeats`` calls (after one warm-up call), ms."""
    call()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(call())
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def own_shape_compile_s(maps, model, encoder) -> float:
    """Seconds a localizer per map spends compiling (each at its map's own shape: no padding)."""
    total = 0.0
    for tactile_map in maps:
        localizer = Localizer([tactile_map], model, encoder)
        total += localizer.compile_s
        localizer.close()
    return total


def one_count(maps, surfaces, count: int, model, encoder, frame, args) -> dict:
    """Every figure of one row: the first ``count`` maps (and their stored surfaces)."""
    chosen = maps[:count]
    imprints = sum(int(np.sum(m.imprint_valid)) for m in chosen)
    start = time.perf_counter()
    localizer = Localizer(chosen, model, encoder, surfaces=surfaces[:count])
    build_s = time.perf_counter() - start
    stack = localizer.stack  # the maps as the live loop holds them
    image, opening, released = frame

    def update():
        localizer.reset()
        return localizer.fuse(image, opening).T_world_object

    def second_update():  # the first grasp untimed, then the same touch again
        update()
        start = time.perf_counter()
        jax.block_until_ready(localizer.fuse(image, opening).T_world_object)
        return time.perf_counter() - start

    row = {"maps": count, "imprints": imprints, "memory_mb": map_megabytes(stack),
           "kb_per_imprint": 1e3 * map_megabytes(stack) / max(imprints, 1), "build_s": build_s,
           "compile_s": localizer.compile_s, "update_ms": median_ms(update, args.repeats),
           "second_update_ms": 1e3 * float(np.median([second_update() for _ in range(args.repeats)])),
           "in_play_after_first": int(localizer.in_play.sum()),
           "frame_ms": median_ms(lambda: localizer(released, opening).T_world_object, args.repeats)}
    localizer.close()
    if count <= args.reference_max:
        row["own_shape_compile_s"] = own_shape_compile_s(chosen, model, encoder)
    if count > 1 and not args.no_identification:
        row["identification_top1"] = float(evaluate_identification(chosen).accuracy())
    return row


def test_frame(args, object_id: str, model):
    """(a contact image, its opening, the gel touching nothing) from the first object's test set."""
    test = new_grasps_set(args, object_id, episodes=1, grasps=1, fingers=1)
    grasps = read_test_grasps(test, ["image", "opening_mm"], object_id=object_id)
    released = np.asarray(np.clip(np.asarray(model.background) * 255.0, 0, 255), np.uint8)
    return np.asarray(grasps["image"]).reshape(-1, *released.shape)[0], float(np.ravel(grasps["opening_mm"])[0]), released


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("maps", nargs="+", metavar="MAP", help="a catalog directory (tactojax map-catalog) or maps")
    parser.add_argument("--counts", default=DEFAULT_COUNTS, help=f"numbers of maps (default {DEFAULT_COUNTS})")
    parser.add_argument("--repeats", type=int, default=10, help="timed calls per latency (default 10)")
    parser.add_argument("--reference-max", type=int, default=5,
                        help="largest count whose own-shape compilations are timed (default 5)")
    parser.add_argument("--no-identification", action="store_true", help="skip the identification column")
    parser.add_argument("--test", help="a new-grasps test set of the first map's object (default: simulated)")
    parser.add_argument("--work", default="benchmark-data/maps", help="where a simulated test set is cached")
    parser.add_argument("--model", default=DEFAULT_MODEL, help=f"shape model (default {DEFAULT_MODEL})")
    parser.add_argument("--encoder", help="retrieval encoder (default: the one the maps record)")
    add_common_arguments(parser, quick="counts 1 and 2, 3 repeats, reference up to 2")
    args = parser.parse_args(argv)
    counts = [1, 2] if args.quick else [int(c) for c in args.counts.split(",")]
    if args.quick:
        args.repeats, args.reference_max = 3, 2
    print_machine()
    paths = expand_catalogs(args.maps)
    counts = [c for c in counts if c <= len(paths)] or [len(paths)]
    model = resolve_shape_model(args.model)
    encoder_name = maps_encoder_name(paths, args.encoder)
    encoder = resolve_encoder(encoder_name)
    maps = [load_tactile_map_with_features(path, encoder_name) for path in paths[:max(counts)]]
    surfaces = [stored_surface(path) for path in paths[:max(counts)]]
    print(f"{sum(s is not None for s in surfaces)} of {len(surfaces)} maps store their surface", flush=True)
    frame = test_frame(args, maps[0].object_id, model)
    rows = []
    for count in counts:
        rows.append(one_count(maps, surfaces, count, model, encoder, frame, args))
        print(f"{count} maps done", flush=True)
    one = rows[0]
    header = ["maps", "imprints", "memory MB", "kB / imprint", "build s", "x 1 map", "compile s", "own shapes s",
              "1st grasp ms (every map)", "x 1 map", "2nd grasp ms", "maps in play", "x 1 map", "frame ms",
              "identification top-1"]
    table = [[r["maps"], r["imprints"], r["memory_mb"], r["kb_per_imprint"], r["build_s"],
              f"{r['build_s'] / one['build_s']:.1f}x", r["compile_s"],
              r.get("own_shape_compile_s", "-"), r["update_ms"], r["update_ms"] / one["update_ms"],
              r["second_update_ms"], r["in_play_after_first"], r["second_update_ms"] / one["second_update_ms"],
              r["frame_ms"], f"{100 * r['identification_top1']:.1f} %" if "identification_top1" in r else "-"]
             for r in rows]
    print(format_table(header, table))
    if args.json:
        write_json(args.json, {"benchmark": "catalog", "machine": machine_info(), "command": " ".join(sys.argv if argv is None else ["catalog.py", *argv]), "maps": paths,
                               "encoder": encoder_name, "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
