"""Speed of the pose belief's update on new grasps, beside CTI-ICP-5 in the same process.

A robot that fuses touches calls :func:`tactojax.localize.update_belief` once per touch: the
first touch of an object (the reference) and every further one (another grasp of the object
where it stands, or the opposite finger of the same grasp). Issue 16 asks for at most 50 ms for
a first touch and 20 ms for each further touch on 2 CPU cores. This script replays the episodes
of a new-grasps test set touch by touch through one jitted update (fixed shapes: it compiles
once) and times every call, interleaved call by call with CTI-ICP-5
(:func:`tactojax.localize.baselines.localize_baseline`, the paper's method) on the same touch, so that the
ratio means something on a busy machine.

Both run twice: compiled as the library compiles its own programs
(:data:`tactojax.localize.COMPILER_OPTIONS`: XLA:CPU without its YNNPACK library fusions, as the
live ``Localizer`` and the evaluations run the belief), and with XLA's defaults (what a plain
``jax.jit`` of ``update_belief`` gets). Reported for each: compile times, the median and 90th
percentile of first and further touches, the CTI-ICP-5 median; and the time to build the map's
localization view
(:meth:`tactojax.localize.LocalizationMap.from_tactile_map`: its surface grid, once per map, on
the host). The belief runs with the object's symmetries (a catalog object) and the calibration
stored in the map's header, if any. Heightmaps and features are computed beforehand (they are
the same for every method: see ``benchmarks/whole_touch.py``).

    python benchmarks/belief_speed.py scissors.npz --test data/test-scissors --json belief_speed.json
    python benchmarks/belief_speed.py --quick     # smoke run: 2 episodes, scissors on a 20 mm map, simulated grasps
"""

from __future__ import annotations

import argparse
import statistics

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
from tactojax.localize.baselines import localize_baseline
from tactojax.localize.evaluation import load_test_episodes


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_map_arguments(parser)
    parser.add_argument("--test", metavar="DIR", help="new-grasps test set of the map's object (default: simulate one)")
    parser.add_argument("--fingers", type=int, default=2, help="fingers fused per grasp (default 2)")
    parser.add_argument("--episodes", type=int, default=16, help="episodes replayed (default 16)")
    add_common_arguments(parser, quick="2 episodes, a 20 mm map", seed_help="CTI-ICP-5's key (and a simulated test set)")
    args = parser.parse_args()
    if args.quick:
        args.episodes = min(args.episodes, 2)
    return args


def replay(args, view, episodes, settings, compiler_options) -> dict:
    """Every touch of the episodes through one jitted belief update, interleaved with CTI-ICP-5
    on the same touch, both compiled with ``compiler_options``: seconds per call (first touches,
    further touches, the reference) and the first calls (compiling) apart."""
    update = jax.jit(update_belief, static_argnames=("settings",), compiler_options=compiler_options)
    cti_icp = jax.jit(lambda touch: localize_baseline(jax.random.key(args.seed), view, touch, method="cti-icp-5"),
                      compiler_options=compiler_options)

    def touch(e, g, f):
        take = lambda x: x[e, g, f]  # noqa: E731
        one = Touch(heightmap=take(episodes.heightmaps), mask=take(episodes.masks), feature=take(episodes.features),
                    opening=episodes.openings[e, g])
        # The sensor poses come in the object frame here: the belief's world is the object's.
        return one, jax.tree.map(take, episodes.T_object_sensor)

    query, T_first = touch(0, 0, 0)
    empty = empty_belief(view, settings)
    out = {"compile_belief_s": seconds_of(lambda: update(view, empty, query, T_first, settings))[0],
           "compile_cti_s": seconds_of(lambda: cti_icp(query))[0], "first": [], "further": [], "reference": []}
    # The first further touch compiles once more if the empty belief's types differ from an
    # updated one's (a weak type): it is timed apart, as the first calls are.
    second, T_second = touch(0, 0, 1) if args.fingers > 1 else touch(0, 1, 0)
    out["compile_further_s"], _ = seconds_of(lambda: update(view, update(view, empty, query, T_first, settings),
                                                            second, T_second, settings))
    out["episodes"] = min(args.episodes, episodes.openings.shape[0])
    for e in range(out["episodes"]):
        belief = empty
        for g in range(episodes.openings.shape[1]):
            for f in range(args.fingers):
                one, T_object_sensor = touch(e, g, f)
                seconds, belief = seconds_of(lambda: update(view, belief, one, T_object_sensor, settings))
                out["first" if g == f == 0 else "further"].append(seconds)
                if not bool(one.mask.any()):
                    continue  # CTI-ICP refuses a touch without contact
                out["reference"].append(seconds_of(lambda: cti_icp(one))[0])
    return out


def ms(values, q=50):
    return 1e3 * float(np.percentile(values, q))


def main() -> None:
    args = parse_args()
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    ((tactile_map, calibration),) = load_maps(args, model, encoder)
    # The view holds the surface grid, the object's symmetries (catalog) and the calibration.
    surface_first_s, view = seconds_of(lambda: LocalizationMap.from_tactile_map(tactile_map, calibration=calibration))
    surface_s, _ = seconds_of(lambda: LocalizationMap.from_tactile_map(tactile_map, calibration=calibration))
    test = new_grasps_set(args, tactile_map.object_id, episodes=args.episodes, grasps=3, fingers=2)
    episodes, fingers = load_test_episodes(test, tactile_map.object_id, model, encoder, progress=False)
    if args.fingers > fingers:
        raise SystemExit(f"--fingers {args.fingers}: the test set records {fingers} finger(s) per grasp")
    settings = BeliefSettings()
    variants = {"library": COMPILER_OPTIONS, "xla_defaults": None} if COMPILER_OPTIONS else {"xla_defaults": None}
    runs = {name: replay(args, view, episodes, settings, options) for name, options in variants.items()}
    summary = {}
    for name, calls in runs.items():
        first, further, reference = calls["first"], calls["further"], calls["reference"]
        summary[name] = {
            "compiler_options": variants[name],
            "first_touch_ms": {"median": ms(first), "p90": ms(first, 90), "calls": len(first)},
            "further_touch_ms": {"median": ms(further), "p90": ms(further, 90), "calls": len(further)},
            "cti_icp_5_ms": {"median": ms(reference), "p90": ms(reference, 90), "calls": len(reference)},
            "compile_s": {"belief": calls["compile_belief_s"], "belief_further": calls["compile_further_s"],
                          "cti_icp_5": calls["compile_cti_s"]},
            "median_first_over_reference": statistics.median(first) / statistics.median(reference),
            "median_further_over_reference": statistics.median(further) / statistics.median(reference)}
    steps = (("belief, first touch", "first_touch_ms", "belief"),
             ("belief, each further touch", "further_touch_ms", "belief_further"),
             ("CTI-ICP-5 (reference)", "cti_icp_5_ms", "cti_icp_5"))
    rows = [[f"{step}{'' if name == 'library' else ' (XLA defaults)'}", row[key]["calls"], row[key]["median"],
             row[key]["p90"], row["compile_s"][compiled]]
            for name, row in summary.items() for step, key, compiled in steps]
    print(format_table(["step", "calls", "median ms", "p90 ms", "first call s (compile)"], rows))
    print(f"map view (surface grid) of {len(view)} imprints (once per map, host): {surface_s:.2f} s "
          f"(first call: {surface_first_s:.2f} s); belief calibration: "
          f"{'stored' if calibration is not None else 'none (default)'}")
    for name, row in summary.items():
        print(f"belief / CTI-ICP-5, median{' (XLA defaults)' if name != 'library' else ''}: first touch "
              f"{row['median_first_over_reference']:.1f}x, further touches {row['median_further_over_reference']:.1f}x")
    headline = summary.get("library", summary["xla_defaults"])
    if args.json:
        write_json(args.json, {
            "map": (map_paths(args) or [tactile_map.object_id])[0], "test": str(test), "fingers": args.fingers,
            "episodes": runs["xla_defaults"]["episodes"], "seed": args.seed,
            "settings": {"sources": settings.sources, "candidates_per_source": settings.grid.size,
                         "screen_points": settings.screen_points, "screened": settings.screened,
                         "registered_sources": getattr(settings, "registered_sources", None),
                         "refine": settings.refine, "hypotheses": settings.hypotheses},
            **headline, "compiled": summary,
            "calibration": None if calibration is None else "stored", "symmetries": len(view.symmetries.wxyz_xyz),
            "map_surface_s": surface_s, "map_surface_first_call_s": surface_first_s,
            "machine": machine_info()})
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
