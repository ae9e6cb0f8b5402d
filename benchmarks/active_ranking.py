"""Speed of the next-grasp ranking (issue 28: 64 candidates in at most 100 ms on 2 CPU cores).

The belief after each episode's first two-finger grasp of a new-grasps test set proposes
``--candidates`` grasps (:func:`tactojax.localize.active.propose_grasps`) and ranks them
(:func:`tactojax.localize.active.next_grasp`); both are timed, compilation apart, interleaved call by
call with the reference in the same process: one belief update (the touch the ranking is for,
:func:`tactojax.localize.update_belief`), so that the ratio means something on a busy machine.

    python benchmarks/active_ranking.py gum_box.npz --test data/fresh-gum_box --json active_ranking.json
    python benchmarks/active_ranking.py --quick   # smoke run: 2 beliefs, scissors on a 20 mm map, simulated grasps
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import numpy as np

try:
    from benchmarks._common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                                    map_paths, new_grasps_set, seconds_of, write_json)
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from _common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info, map_paths,
                         new_grasps_set, seconds_of, write_json)

from tactojax.io import resolve_encoder, resolve_shape_model
from tactojax.localize import COMPILER_OPTIONS, BeliefSettings, LocalizationMap, Touch, empty_belief, update_belief
from tactojax.localize.active import ActiveSettings, map_marching_grid, next_grasp, propose_grasps
from tactojax.localize.evaluation import load_test_episodes


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_map_arguments(parser)
    parser.add_argument("--test", metavar="DIR", help="new-grasps test set (two fingers; default: simulate one)")
    parser.add_argument("--episodes", type=int, default=8, help="episodes (beliefs) timed (default 8)")
    parser.add_argument("--candidates", type=int, default=64)
    parser.add_argument("--hypotheses", type=int, default=8)
    add_common_arguments(parser, quick="2 beliefs, a 20 mm map", seed_help="candidate grasps (and a simulated test set)")
    args = parser.parse_args()
    if args.quick:
        args.episodes = min(args.episodes, 2)
    return args


def time_ranking(args, view, grid, episodes) -> dict[str, list[float]]:
    """Seconds of every call: the two belief updates of each episode's first grasp (the
    reference), proposing candidates and ranking them."""
    settings, belief_settings = ActiveSettings(hypotheses=args.hypotheses), BeliefSettings()
    # Compiled as the proposal and the ranking are (tactojax.localize.COMPILER_OPTIONS).
    update = jax.jit(update_belief, static_argnames=("settings",), compiler_options=COMPILER_OPTIONS)
    times = {"propose": [], "rank": [], "update": []}
    for e in range(min(args.episodes, episodes.openings.shape[0])):
        belief = empty_belief(view, belief_settings)
        for finger in range(2):
            touch = Touch(heightmap=episodes.heightmaps[e, 0, finger], mask=episodes.masks[e, 0, finger],
                          feature=episodes.features[e, 0, finger], opening=episodes.openings[e, 0])
            T = jax.tree.map(lambda x: x[e, 0, finger], episodes.T_object_sensor)
            seconds, belief = seconds_of(lambda: update(view, belief, touch, T, settings=belief_settings))
            times["update"].append(seconds)
        seconds, (poses, _) = seconds_of(lambda: propose_grasps(jax.random.key(args.seed + e), view, grid, belief,
                                                              args.candidates, settings))
        times["propose"].append(seconds)
        seconds, _ = seconds_of(lambda: next_grasp(view, grid, belief, poses, settings))
        times["rank"].append(seconds)
    return times


def main() -> None:
    args = parse_args()
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    ((tactile_map, calibration),) = load_maps(args, model, encoder)
    view = LocalizationMap.from_tactile_map(tactile_map, calibration=calibration)
    start = time.perf_counter()
    grid = map_marching_grid(view)
    grid_s = time.perf_counter() - start
    test = new_grasps_set(args, tactile_map.object_id, episodes=args.episodes, grasps=1, fingers=2)
    episodes, _ = load_test_episodes(test, tactile_map.object_id, model, encoder, progress=False)
    times = time_ranking(args, view, grid, episodes)
    rows, result = [], {"machine": machine_info(), "map": (map_paths(args) or [tactile_map.object_id])[0],
                        "candidates": args.candidates, "hypotheses": args.hypotheses, "marching_grid_s": grid_s,
                        "seed": args.seed}
    for name, values in times.items():
        first, steady = values[0], values[1:] if name != "update" else values[2:]
        result[name] = {"first_s": first, "median_s": statistics.median(steady), "calls": len(steady),
                        "p90_s": float(np.quantile(steady, 0.9))}
        rows.append([name, f"{first:.2f}", f"{1000 * statistics.median(steady):.1f}",
                     f"{1000 * result[name]['p90_s']:.1f}", len(steady)])
    print(format_table(["step", "first call (s, compiles)", "median (ms)", "p90 (ms)", "calls"], rows))
    print(f"marching grid (host, once per map): {grid_s:.2f} s; rank / one belief update: "
          f"{result['rank']['median_s'] / result['update']['median_s']:.2f}")
    if args.json:
        write_json(args.json, result)
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
