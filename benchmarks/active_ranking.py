"""Speed of the next-grasp ranking (issue 28: 64 candidates in at most 100 ms on 2 CPU cores).

The belief after each episode's first two-finger grasp of a new-grasps test set proposes
``--candidates`` grasps (:func:`tactojax.localize.propose_grasps`) and ranks them
(:func:`tactojax.localize.next_grasp`); both are timed, compilation apart, interleaved call by
call with the reference in the same process: one belief update (the touch the ranking is for,
:func:`tactojax.localize.update_belief`), so that the ratio means something on a busy machine.

    python benchmarks/active_ranking.py gum_box.npz --test data/fresh-gum_box --json active_ranking.json
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import numpy as np

try:
    from benchmarks._common import format_table, machine_info, seconds_of, write_json
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from _common import format_table, machine_info, seconds_of, write_json

from tactojax.io import DEFAULT_ENCODER, load_localization_map, resolve_encoder, resolve_shape_model
from tactojax.localize import (ActiveSettings, BeliefSettings, Touch, empty_belief, load_test_episodes,
                               map_marching_grid, next_grasp, propose_grasps, update_belief)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("map", help="the object's tactile map (.npz)")
    parser.add_argument("--test", required=True, metavar="DIR", help="new-grasps test set (two fingers)")
    parser.add_argument("--episodes", type=int, default=8, help="episodes (beliefs) timed (default 8)")
    parser.add_argument("--candidates", type=int, default=64)
    parser.add_argument("--hypotheses", type=int, default=8)
    parser.add_argument("--model", default="bundled:fast-gelslim-0.5", help="shape model")
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args()

    view = load_localization_map(args.map)
    start = time.perf_counter()
    grid = map_marching_grid(view)
    grid_s = time.perf_counter() - start
    episodes, _ = load_test_episodes(args.test, view_object(args.map), resolve_shape_model(args.model),
                                     resolve_encoder(DEFAULT_ENCODER), progress=False)
    settings, belief_settings = ActiveSettings(hypotheses=args.hypotheses), BeliefSettings()
    update = jax.jit(update_belief, static_argnames=("settings",))
    times = {"propose": [], "rank": [], "update": []}
    for e in range(min(args.episodes, episodes.openings.shape[0])):
        belief = empty_belief(view, belief_settings)
        for finger in range(2):
            touch = Touch(heightmap=episodes.heightmaps[e, 0, finger], mask=episodes.masks[e, 0, finger],
                          feature=episodes.features[e, 0, finger], opening=episodes.openings[e, 0])
            T = jax.tree.map(lambda x: x[e, 0, finger], episodes.T_object_sensor)
            seconds, belief = seconds_of(lambda: update(view, belief, touch, T, settings=belief_settings))
            times["update"].append(seconds)
        seconds, (poses, _) = seconds_of(lambda: propose_grasps(jax.random.key(e), view, grid, belief, args.candidates,
                                                              settings))
        times["propose"].append(seconds)
        seconds, _ = seconds_of(lambda: next_grasp(view, grid, belief, poses, settings))
        times["rank"].append(seconds)
    rows, result = [], {"machine": machine_info(), "map": args.map, "candidates": args.candidates,
                        "hypotheses": args.hypotheses, "marching_grid_s": grid_s}
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


def view_object(path: str) -> str:
    """The object id a map file stores."""
    from tactojax.io import tactile_map_metadata

    return tactile_map_metadata(path)["object_id"]


if __name__ == "__main__":
    main()
