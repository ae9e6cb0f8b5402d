"""Throughput of the batched, sharded evaluations: touches/s and episodes/s on every device.

The evaluations run as one compiled program each, vmapped over their batch (touches, episodes,
leave-one-out queries) and sharded over the devices (a mesh with one ``batch`` axis; see
:func:`tactojax.localize.evaluation.evaluate_new_grasps` and :func:`tactojax.localize.evaluation.evaluate_localization`).
This script times them on a map and a new-grasps test set:

- **single touches**: every grasp's sensor-finger touch localized alone, with CTI-ICP-5 (the
  paper's method) and with the belief (touches/s; for the belief, each touch as an episode of
  one touch, so that the fused episodes are timed apart);
- **fused episodes**: the belief fused over the grasps of each episode, 2 fingers (episodes/s);
- **leave-one-out**: the map's own imprints as queries, CTI-ICP-5 and the belief (queries/s;
  the belief rebuilds the map's surface without each fold's queries on the host, included).

Each evaluation's first call (tracing and compilation, and the run) is reported apart from the
steady state (the median of ``--repeats`` further calls). The reference in the same run is the
same evaluation on one device, when there are several. On a CPU,
``XLA_FLAGS=--xla_force_host_platform_device_count=2`` gives two devices. The map is the
object's simulated map (``--object``, built once under ``--work``) or a saved one with ``--test``.

    python benchmarks/batch_eval.py --object scissors --json batch_eval.json
    python benchmarks/batch_eval.py scissors.npz --test data/test-scissors --json batch_eval.json
    python benchmarks/batch_eval.py --quick    # smoke run: 4 episodes of 2 grasps, 8 queries, a 20 mm map
    python benchmarks/batch_eval.py --quick --episodes 32 --queries 64   # the full batch on the 20 mm map
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

try:  # run as ``python benchmarks/batch_eval.py`` or as a module
    from benchmarks._common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                                    map_paths, new_grasps_set, print_machine, time_call, write_json)
except ImportError:
    from _common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info, map_paths,
                         new_grasps_set, print_machine, time_call, write_json)

from tactojax.io import resolve_encoder, resolve_shape_model
from tactojax.localize import LocalizationMap
from tactojax.localize.evaluation import (
    evaluate_localization,
    evaluate_new_grasps,
    load_test_episodes,
)


UNITS = {"touch": "touches", "episode": "episodes", "query": "queries"}


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_map_arguments(parser)
    parser.add_argument("--test", metavar="DIR", help="new-grasps test set of the map's object, 2 fingers "
                                                      "(default: simulate one under --work)")
    parser.add_argument("--episodes", type=int, help="episodes of a simulated test set (default 32; --quick 4)")
    parser.add_argument("--queries", type=int, help="leave-one-out queries (default 64; --quick 8)")
    parser.add_argument("--touch-batch-size", type=int, default=8,
                        help="single touches a device localizes at once, vmapped (default 8)")
    parser.add_argument("--episode-batch-size", type=int, default=1,
                        help="episodes a device fuses at once, vmapped (default 1: one at a time)")
    parser.add_argument("--query-batch-size", type=int, default=32,
                        help="leave-one-out queries a device localizes at once with CTI-ICP-5 (default 32; "
                             "the belief: 4)")
    parser.add_argument("--no-reference", action="store_true",
                        help="skip the one-device reference when there are several devices")
    add_common_arguments(parser, quick="4 episodes of 2 grasps, 8 queries (unless given), a 20 mm map, 1 repeat",
                         repeats=2, seed_help="a simulated test set and the baselines' key")
    args = parser.parse_args()
    args.episodes = args.episodes or (4 if args.quick else 32)
    args.queries = args.queries or (8 if args.quick else 64)
    if args.quick:
        args.repeats = 1
    return args


def evaluations(args, tactile_map, calibration, view, episodes) -> dict:
    """``{name: (items, unit, call(devices))}``: every timed evaluation, on the given devices."""
    grasps = int(np.prod(episodes.openings.shape))
    valid = np.flatnonzero(np.asarray(tactile_map.imprint_valid))
    queries = np.sort(np.random.default_rng(args.seed).choice(valid, min(args.queries, len(valid)), replace=False))
    key = jax.random.key(args.seed)
    batching = {"touch_batch_size": args.touch_batch_size, "episode_batch_size": args.episode_batch_size}

    def new_grasps(method, test=episodes, **options):
        options = {**batching, **options}
        return lambda devices: evaluate_new_grasps(view, test, (method,), devices=devices, **options)

    # The belief's single touches: every touch an episode of its own (one touch fused: the same
    # work as localizing it alone, as many at once), so that the fused episodes are timed apart.
    alone = episodes.sensor_touches()

    def leave_one_out(method):
        return lambda devices: evaluate_localization(key, tactile_map, (method,), calibration=calibration,
                                                     symmetries=view.symmetries, queries=queries, devices=devices,
                                                     chunk_size=args.query_batch_size)

    return {
        "single touches, CTI-ICP-5": (grasps, "touch", new_grasps("cti-icp-5")),
        "single touches, belief": (grasps, "touch", new_grasps("belief", alone, single_touches=False,
                                                                  episode_batch_size=args.touch_batch_size)),
        "fused episodes, belief, 2 fingers": (episodes.openings.shape[0], "episode",
                                              new_grasps("belief", fingers=2, single_touches=False)),
        "leave-one-out, CTI-ICP-5": (len(queries), "query", leave_one_out("cti-icp-5")),
        "leave-one-out, belief": (len(queries), "query", leave_one_out("belief")),
    }


def main() -> None:
    args = parse_args()
    print_machine()
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    ((tactile_map, calibration),) = load_maps(args, model, encoder)
    name = tactile_map.object_id
    test = new_grasps_set(args, name, episodes=args.episodes, grasps=2 if args.quick else 3, fingers=2)
    episodes, fingers = load_test_episodes(test, name, model, encoder, progress=False)
    if fingers < 2:
        raise SystemExit(f"{test}: the test set records {fingers} finger per grasp; 2 are fused here")
    view = LocalizationMap.from_tactile_map(tactile_map, calibration=calibration)
    devices = jax.devices()
    runs = [("all", devices)] + ([("one", devices[:1])] if len(devices) > 1 and not args.no_reference else [])
    rows, records = [], []
    for label, (items, unit, call) in evaluations(args, tactile_map, calibration, view, episodes).items():
        for run, chosen in runs:
            print(f"{label} on {len(chosen)} device(s) ...", flush=True)
            timing = time_call(call, chosen, repeats=args.repeats)
            rate = items / timing["median_s"]
            records.append({"evaluation": label, "devices": len(chosen), "items": items, "unit": unit,
                            "per_second": rate, **timing})
            rows.append([label, len(chosen), f"{items} {UNITS[unit]}", rate, timing["median_s"], timing["compile_s"]])
    print(format_table(["evaluation", "devices", "batch", "per second", "steady s", "compile s (first - steady)"],
                       rows))
    for label in dict.fromkeys(r["evaluation"] for r in records):
        pair = [r for r in records if r["evaluation"] == label]
        if len(pair) == 2:
            print(f"{label}: {len(devices)} devices / 1 device: {pair[0]['per_second'] / pair[1]['per_second']:.2f}x")
    info = machine_info()
    print(f"{name}: {len(tactile_map)} imprints, {episodes.openings.shape[0]} episodes x "
          f"{episodes.openings.shape[1]} grasps x 2 fingers; {len(devices)} {info['jax_device_kind']} device(s)")
    if args.json:
        write_json(args.json, {
            "object": name, "map": (map_paths(args) or [name])[0], "test": str(test), "imprints": len(tactile_map),
            "episodes": int(episodes.openings.shape[0]), "grasps_per_episode": int(episodes.openings.shape[1]),
            "fingers": 2, "seed": args.seed, "repeats": args.repeats,
            "device_kind": info["jax_device_kind"], "device_count": len(devices),
            "batch_sizes": {"touches": args.touch_batch_size, "episodes": args.episode_batch_size,
                            "queries": args.query_batch_size},
            "calibration": None if calibration is None else "stored", "results": records, "machine": info})
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
