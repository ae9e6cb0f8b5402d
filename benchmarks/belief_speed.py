"""Speed of the pose belief's update on new grasps, beside CTI-ICP-5 in the same process.

A robot that fuses touches calls :func:`tactojax.localize.update_belief` once per touch: the
first touch of an object (the reference) and every further one (another grasp of the object
where it stands, or the opposite finger of the same grasp). Issue 16 asks for at most 50 ms for
a first touch and 20 ms for each further touch on 2 CPU cores. This script replays the episodes
of a new-grasps test set touch by touch through one jitted update (fixed shapes: it compiles
once) and times every call, interleaved call by call with CTI-ICP-5
(:func:`tactojax.localize.localize_baseline`, the paper's method) on the same touch, so that the
ratio means something on a busy machine.

Reported: compile times, the median and 90th percentile of first and further touches, the
CTI-ICP-5 median, and the time to build the map's localization view
(:meth:`tactojax.localize.LocalizationMap.from_tactile_map`: its surface grid, once per map, on
the host). The belief runs with the object's symmetries (a catalog object) and the calibration
stored in the map's header, if any. Heightmaps and features are computed beforehand (they are
the same for every method: see ``benchmarks/whole_touch.py``).

    python benchmarks/belief_speed.py scissors.npz --test data/test-scissors --json belief_speed.json
"""

from __future__ import annotations

import argparse
import statistics

import jax
import numpy as np

try:
    from benchmarks._common import format_table, machine_info, seconds_of, write_json
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from _common import format_table, machine_info, seconds_of, write_json

from tactojax.features import encode_images
from tactojax.io import DEFAULT_ENCODER, load_tactile_map, resolve_encoder, resolve_shape_model, tactile_map_metadata
from tactojax.localize import (BeliefSettings, LocalizationMap, Touch, calibration_from_json, empty_belief,
                               load_test_episodes, localize_baseline, update_belief)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("map", help="the object's tactile map (.npz)")
    parser.add_argument("--test", required=True, metavar="DIR", help="new-grasps test set of the map's object")
    parser.add_argument("--fingers", type=int, default=2, help="fingers fused per grasp (default 2)")
    parser.add_argument("--episodes", type=int, default=16, help="episodes replayed (default 16)")
    parser.add_argument("--encoder", default=DEFAULT_ENCODER, help=f"retrieval encoder (default {DEFAULT_ENCODER})")
    parser.add_argument("--model", default="bundled:fast-gelslim-0.5", help="shape model")
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args()

    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    tactile_map = load_tactile_map(args.map, images=True)
    tactile_map = tactile_map.with_features(encode_images(encoder, tactile_map.stored_images(), progress=False))
    stored = tactile_map_metadata(args.map).get("metadata", {}).get("belief_calibration")
    calibration = None if stored is None else calibration_from_json(stored)
    # The view holds the surface grid, the object's symmetries (catalog) and the calibration.
    surface_first_s, view = seconds_of(lambda: LocalizationMap.from_tactile_map(tactile_map, calibration=calibration))
    surface_s, _ = seconds_of(lambda: LocalizationMap.from_tactile_map(tactile_map, calibration=calibration))
    symmetries = view.symmetries
    episodes, fingers = load_test_episodes(args.test, tactile_map.object_id, model, encoder, progress=False)
    if args.fingers > fingers:
        raise SystemExit(f"--fingers {args.fingers}: the test set records {fingers} finger(s) per grasp")

    settings = BeliefSettings()
    update = jax.jit(update_belief, static_argnames=("settings",))

    def cti_icp(touch):
        return localize_baseline(jax.random.key(0), view, touch, method="cti-icp-5")

    def touch(e, g, f):
        take = lambda x: x[e, g, f]  # noqa: E731
        one = Touch(heightmap=take(episodes.heightmaps), mask=take(episodes.masks), feature=take(episodes.features),
                    opening=episodes.openings[e, g])
        # The sensor poses come in the object frame here: the belief's world is the object's.
        return one, jax.tree.map(take, episodes.T_object_sensor)

    query, T_first = touch(0, 0, 0)
    empty = empty_belief(view, settings)
    compile_belief_s, _ = seconds_of(lambda: update(view, empty, query, T_first, settings))
    compile_cti_s, _ = seconds_of(lambda: cti_icp(query))
    first, further, reference = [], [], []
    count = min(args.episodes, episodes.openings.shape[0])
    # The first further touch compiles once more if the empty belief's types differ from an
    # updated one's (a weak type): it is timed apart, as the first calls are.
    second, T_second = touch(0, 0, 1) if args.fingers > 1 else touch(0, 1, 0)
    compile_further_s, _ = seconds_of(lambda: update(view, update(view, empty, query, T_first, settings), second,
                                                   T_second, settings))
    for e in range(count):
        belief = empty
        for g in range(episodes.openings.shape[1]):
            for f in range(args.fingers):
                one, T_object_sensor = touch(e, g, f)
                seconds, belief = seconds_of(lambda: update(view, belief, one, T_object_sensor, settings))
                (first if g == f == 0 else further).append(seconds)
                if not bool(one.mask.any()):
                    continue  # CTI-ICP refuses a touch without contact
                reference.append(seconds_of(lambda: cti_icp(one))[0])

    def ms(values, q=50):
        return 1e3 * float(np.percentile(values, q))

    rows = [["belief, first touch", len(first), ms(first), ms(first, 90), compile_belief_s],
            ["belief, each further touch", len(further), ms(further), ms(further, 90), compile_further_s],
            ["CTI-ICP-5 (reference)", len(reference), ms(reference), ms(reference, 90), compile_cti_s]]
    print(format_table(["step", "calls", "median ms", "p90 ms", "first call s (compile)"], rows))
    print(f"map view (surface grid) of {len(view)} imprints (once per map, host): {surface_s:.2f} s "
          f"(first call: {surface_first_s:.2f} s); belief calibration: {'stored' if stored else 'none (default)'}")
    print(f"belief / CTI-ICP-5, median: first touch {ms(first) / ms(reference):.1f}x, "
          f"further touches {ms(further) / ms(reference):.1f}x")
    if args.json:
        write_json(args.json, {
            "map": args.map, "test": args.test, "fingers": args.fingers, "episodes": count,
            "settings": {"sources": settings.sources, "candidates_per_source": settings.grid.size,
                         "screen_points": settings.screen_points, "screened": settings.screened,
                         "registered_sources": getattr(settings, "registered_sources", None),
                         "refine": settings.refine, "hypotheses": settings.hypotheses},
            "first_touch_ms": {"median": ms(first), "p90": ms(first, 90), "calls": len(first)},
            "further_touch_ms": {"median": ms(further), "p90": ms(further, 90), "calls": len(further)},
            "cti_icp_5_ms": {"median": ms(reference), "p90": ms(reference, 90), "calls": len(reference)},
            "compile_s": {"belief": compile_belief_s, "belief_further": compile_further_s, "cti_icp_5": compile_cti_s},
            "calibration": stored, "symmetries": len(symmetries.wxyz_xyz),
            "map_surface_s": surface_s, "map_surface_first_call_s": surface_first_s,
            "median_further_over_reference": statistics.median(further) / statistics.median(reference),
            "machine": machine_info()})


if __name__ == "__main__":
    main()
