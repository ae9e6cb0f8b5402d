"""Retrieval encoders side by side: speed per touch, kernels, retrieval recall, localization.

For each encoder (the first is the reference, by default ImageNet EfficientNet-Lite0):

- **speed**: one 120 x 160 image (a map's first imprint) through the encoder's whole input
  pipeline and network, jitted; compile time apart, the steady-state median of ``--repeats``
  calls in interleaved rounds of 10 (every encoder timed in each round, so a busy machine slows
  them alike), and the kernels one call launches (``tactojax.kernel_count``);
- **recall@N** per map (``localization_ceiling.retrieval_recall``): how often the N most similar
  imprints of a leave-one-out query hold a true neighbour;
- **leave-one-out CTI-ICP-5**: median RMSE (mm) over the same queries (symmetry-aware in
  brackets for symmetric catalog objects), as ``tactojax eval-localization MAP --queries Q``;
- **new grasps** (``--test DIR``, a test set of some of the maps' objects): the single-touch
  CTI-ICP-5 median, by ``tactojax eval-localization MAP... --test DIR --fingers F --methods cti-icp-5``.

    python benchmarks/features.py scissors.npz screwdriver.npz large_marker.npz \\
        --test data/test --json features.json     # ImageNet against bundled:features-tactile
    python benchmarks/features.py --quick       # smoke run: 20 calls, 10 queries, scissors on a 20 mm map
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from tactojax import kernel_count
from tactojax.cli import main as cli_main
from tactojax.features import apply_encoder, encode_images
from tactojax.io import load_tactile_map, open_dataset, resolve_encoder, resolve_shape_model
from tactojax.localize.evaluation import evaluate_localization

try:  # run as ``python benchmarks/features.py`` or as a module
    from benchmarks._common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                                    map_paths, write_json)
    from benchmarks.localization_ceiling import retrieval_recall
except ImportError:
    from _common import add_common_arguments, add_map_arguments, format_table, load_maps, machine_info, map_paths, write_json
    from localization_ceiling import retrieval_recall

RECALL_AT = (1, 5, 15, 50)
CALLS_PER_ROUND = 10
"""Timed calls of one encoder before the next encoder's (``--repeats`` of each, in rounds)."""


def encoder_speed(encoders: dict, image: np.ndarray, *, rounds: int, calls: int) -> dict:
    """Per encoder: compile seconds, kernels, and the steady-state median ms of one image."""
    single = jax.jit(lambda encoder, x: apply_encoder(encoder, x[None])[0])
    compiled, result = {}, {}
    for name, encoder in encoders.items():
        start = time.perf_counter()
        compiled[name] = single.lower(encoder, image).compile()
        result[name] = {"compile_s": time.perf_counter() - start, "kernels": kernel_count(compiled[name])}
        jax.block_until_ready(compiled[name](encoder, image))
    times = {name: [] for name in encoders}
    for _ in range(rounds):
        for name, encoder in encoders.items():
            for _ in range(calls):
                start = time.perf_counter()
                jax.block_until_ready(compiled[name](encoder, image))
                times[name].append(time.perf_counter() - start)
    for name in encoders:
        result[name]["median_ms"] = 1e3 * statistics.median(times[name])
        result[name]["p90_ms"] = 1e3 * float(np.percentile(times[name], 90))
    return result


def leave_one_out(tactile_map, queries: np.ndarray) -> dict:
    """CTI-ICP-5 median RMSE over ``queries`` (and symmetry-aware for symmetric objects)."""
    result = evaluate_localization(jax.random.key(0), tactile_map, ["cti-icp-5"], queries=queries,
                                   progress=True)["cti-icp-5"]  # the map's symmetries
    summary = result.summary()
    symmetric = tactile_map.object_symmetry.symmetric
    return {"median_mm": summary["rmse_mm"]["median"],
            "symmetric_median_mm": summary["symmetric_rmse_mm"]["median"] if symmetric else None,
            "within_2mm": summary["within_mm"]["2"]}


def new_grasps(maps: list[str], encoder: str, test: str, fingers: int) -> dict:
    """Single-touch CTI-ICP-5 of a new-grasps test set through the CLI, per object."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "new.json"
        code = cli_main(["eval-localization", *maps, "--test", test, "--fingers", str(fingers), "--methods",
                         "cti-icp-5", "--encoder", encoder, "--json", str(out), "--figure", str(Path(folder) / "new.png")])
        if code != 0:
            raise RuntimeError(f"eval-localization --test failed for {encoder}")
        payload = json.loads(out.read_text())
    results = {}
    for name, entry in payload["objects"].items():
        single = next(r for r in entry["results"] if r["method"] == "cti-icp-5")
        results[name] = {"count": single["count"], "median_mm": single["median_rmse_mm"],
                         "symmetric_median_mm": single.get("median_symmetric_rmse_mm") if entry["symmetric"] else None}
    return results


def _mm(entry: dict | None) -> str:
    if entry is None:
        return "-"
    text = f"{entry['median_mm']:.1f}"
    return text if entry.get("symmetric_median_mm") is None else f"{text} ({entry['symmetric_median_mm']:.1f})"


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_map_arguments(parser, several=True)
    parser.add_argument("--encoders", nargs="+", default=["imagenet:efficientnet-lite0", "bundled:features-tactile"],
                        help="encoders to compare; the first is the reference")
    parser.add_argument("--queries", type=int, default=200, help="leave-one-out queries per map (default 200)")
    parser.add_argument("--test", metavar="DIR", help="new-grasps test set of the maps' objects")
    parser.add_argument("--fingers", type=int, default=2, help="fingers of the test set (default 2)")
    parser.add_argument("--no-localization", action="store_true", help="only speed and recall")
    add_common_arguments(parser, quick="20 timed calls, 10 queries, a 20 mm map",
                         seed_help="query choice, as eval-localization's --seed", repeats=200,
                         repeats_help=f"timed calls per encoder, in rounds of {CALLS_PER_ROUND}")
    args = parser.parse_args()
    if args.quick:
        args.repeats, args.queries = min(args.repeats, 20), min(args.queries, 10)
    return args


def per_object(args, maps: list, encoders: dict) -> dict:
    """Per map and encoder: recall@N and (unless ``--no-localization``) leave-one-out CTI-ICP-5
    on the same queries, and new grasps of ``--test``."""
    objects: dict[str, dict] = {}
    for tactile_map in maps:
        valid = np.flatnonzero(np.asarray(tactile_map.imprint_valid))
        queries = valid
        if args.queries < len(valid):
            queries = np.sort(np.random.default_rng(args.seed).choice(valid, args.queries, replace=False))
        per_encoder = {}
        for name, encoder in encoders.items():
            featured = tactile_map.with_features(encode_images(encoder, tactile_map.stored_images(), progress=True))
            entry = {"recall": retrieval_recall(featured, queries, RECALL_AT)}
            if not args.no_localization:
                entry["leave_one_out"] = leave_one_out(featured, queries)
            per_encoder[name] = entry
        objects[tactile_map.object_id] = {"imprints": len(tactile_map), "queries": len(queries),
                                          "encoders": per_encoder}
    if args.test and not args.no_localization:
        tested = set(open_dataset(args.test).read(["object_id"])["object_id"].astype(str).tolist())
        paths = [path for path, m in zip(map_paths(args), maps) if m.object_id in tested]
        for name in args.encoders:
            for object_id, result in new_grasps(paths, name, args.test, args.fingers).items():
                objects[object_id]["encoders"][name]["new_grasps"] = result
    return objects


def print_results(args, speed: dict, objects: dict, image_shape) -> None:
    reference = args.encoders[0]
    print(f"one {image_shape[0]} x {image_shape[1]} image, {args.repeats} calls per encoder")
    print(format_table(["encoder", "median ms", "p90 ms", "x reference", "kernels", "compile s"],
                       [[name, f"{s['median_ms']:.2f}", f"{s['p90_ms']:.2f}",
                         f"{s['median_ms'] / speed[reference]['median_ms']:.3f}", s["kernels"], f"{s['compile_s']:.1f}"]
                        for name, s in speed.items()]))
    rows = []
    for object_id, entry in objects.items():
        for name, result in entry["encoders"].items():
            rows.append([object_id, name, f"{speed[name]['median_ms']:.2f}", speed[name]["kernels"],
                         " / ".join(f"{100 * result['recall'][str(k)]:.0f}" for k in RECALL_AT),
                         _mm(result.get("leave_one_out")), _mm(result.get("new_grasps"))])
    print(format_table(["object", "encoder", "ms", "kernels", "recall@" + "/".join(map(str, RECALL_AT)) + " %",
                        f"leave-one-out CTI-ICP-5 median mm ({args.queries} queries)",
                        "new grasps CTI-ICP-5 median mm (1 touch)"], rows))


def main() -> None:
    args = parse_args()
    if map_paths(args):
        maps = [load_tactile_map(path, images=True) for path in map_paths(args)]
    else:  # --object, simulated and mapped (its features are replaced by each encoder's below)
        maps = [m for m, _ in load_maps(args, resolve_shape_model(args.model), resolve_encoder(args.encoder))]
    encoders = {name: resolve_encoder(name) for name in args.encoders}
    image = np.asarray(maps[0].stored_images()[0])
    rounds = max(1, args.repeats // CALLS_PER_ROUND)
    speed = encoder_speed(encoders, image, rounds=rounds, calls=min(args.repeats, CALLS_PER_ROUND))
    objects = per_object(args, maps, encoders)
    print_results(args, speed, objects, image.shape)
    if args.json:
        write_json(args.json, {"speed": speed, "objects": objects, "reference": args.encoders[0],
                               "queries": args.queries, "test": args.test, "fingers": args.fingers,
                               "repeats": args.repeats, "seed": args.seed, "machine": machine_info()})
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
