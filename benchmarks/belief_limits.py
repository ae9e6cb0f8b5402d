"""What limits the fused pose belief on new grasps: the map's surface, the predicted touches, or the search?

The belief scores every hypothesis by how its touches fit the map's signed-distance surface
(built from the map's *predicted* heightmaps), using each touch's *predicted* heightmap and
contact mask. This script swaps in exact data one part at a time and runs the same belief
(:func:`tactojax.localize.evaluation.evaluate_new_grasps`) on the same episodes:

- **surface**: the map's; the object's true signed distance (the simulator's solid) on the same
  grid, at the cells where the map knows its surface (exact values, the map's coverage); or the
  true signed distance known wherever it is within the map's reach of the surface (the whole
  object, as if every part of it had been felt). The first two differ by the map's accuracy,
  the last two by its coverage;
- **touches**: the shape model's heightmaps and contact masks, or the simulator's.

When exact data lifts the share within 2 mm, the data (local shape, mapping) is the limit; when
exact data still misses, the touches do not carry the information or the search does not find
it. Then, for every episode still more than 2 mm off after all its grasps (the map's surface,
predicted touches), where its touches land on the map at the true pose and at the belief's best:
how many contact points of its worst touch fall where the map knows no surface, and how well
the others fit (a touch reaching past what the map stored is scored as floating in space); and
whether the belief scores the truth (refined by its own ICP) above its best, so that its search
missed it, or below, so that its likelihood prefers the wrong pose
(:func:`~tactojax.localize.evaluation.truth_against_best`).

Errors are the paper's cloud RMSE, up to the object's symmetry for a symmetric one (the
catalog's). Needs a catalog object (its true solid: a primitive's signed distance, or a mesh's
from trimesh). The map's stored belief calibration is used.

    python benchmarks/belief_limits.py gum_box.npz --test data/dev-gum_box --json limits.json
    python benchmarks/belief_limits.py --quick     # smoke run: 2 episodes of 2 grasps, scissors on a 20 mm map
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from tactojax.io import read_test_grasps, resolve_encoder, resolve_shape_model
from tactojax.localize import LocalizationMap, MapSurface
from tactojax.localize.evaluation import episode_beliefs, evaluate_new_grasps, load_test_episodes, truth_against_best
from tactojax.objects import get_object

try:  # run as ``python benchmarks/belief_limits.py`` or as a module
    from benchmarks._common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                                    map_paths, new_grasps_set, write_json)
except ImportError:
    from _common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info, map_paths,
                         new_grasps_set, write_json)

REACH_MM = 1.5
"""The true surface is known where the object's surface is this close (the map's own reach), mm."""


def true_surface(view: LocalizationMap, distance: np.ndarray, keep: np.ndarray) -> LocalizationMap:
    """``view`` with its surface grid replaced by the object's exact signed distance
    (:func:`true_distance`) at the cells ``keep`` (NaN, unknown, elsewhere): the cells within the
    reach of the object's surface (the whole object, felt or not), or those where the map knows
    its surface (its coverage, exact values)."""
    surface = view.surface
    return view.replace(surface=MapSurface.from_dense(np.where(keep, distance, np.nan).astype(np.float32),
                                                      surface.origin, surface.pitch_mm))


def true_distance(view: LocalizationMap, object_id: str, reach_mm: float = REACH_MM) -> tuple[np.ndarray, np.ndarray]:
    """The object's signed distance (mm, > 0 outside) at every cell of the map's surface grid
    where the map knows its surface or the object's surface is within ``reach_mm`` (+inf at the
    other cells of a mesh object), and where the map knows it."""
    solid = get_object(object_id).solid
    surface = view.surface
    known = np.isfinite(np.asarray(surface.distance))
    cells = np.stack(np.meshgrid(*(np.arange(n) for n in surface.shape), indexing="ij"), -1).reshape(-1, 3)
    centres = np.asarray(surface.origin, np.float64) + cells * surface.pitch_mm
    if hasattr(solid, "sdf"):  # a primitive: its exact signed distance, in JAX
        distance = np.asarray(jax.lax.map(solid.sdf, jnp.asarray(centres, jnp.float32), batch_size=4096))
        return distance.reshape(surface.shape), known
    # A mesh: trimesh's signed distance (> 0 inside) at the cells near its surface (a dense sample
    # of it finds them) or known to the map; the others are farther than the reach.
    import trimesh
    from scipy.spatial import cKDTree

    mesh = solid.mesh
    spacing = surface.pitch_mm / 2
    samples, _ = trimesh.sample.sample_surface_even(mesh, int(mesh.area / spacing ** 2) + 1, seed=0)
    near, _ = cKDTree(samples).query(centres, distance_upper_bound=reach_mm + surface.pitch_mm, workers=-1)
    ask = np.isfinite(near) | known.reshape(-1)
    distance = np.full(len(centres), np.inf)
    distance[ask] = -trimesh.proximity.signed_distance(mesh, centres[ask])
    return distance.reshape(surface.shape), known


def coverage(distance: np.ndarray, known: np.ndarray, reach_mm: float = REACH_MM) -> float:
    """The share of the object's surface shell (cells within ``reach_mm`` of it: :func:`true_distance`)
    where the map knows its surface."""
    return float(np.mean(known[np.abs(distance) <= reach_mm]))


def exact_touches(episodes, test, object_id: str):
    """``episodes`` with the simulator's heightmaps and contact masks instead of the predicted ones."""
    truth = read_test_grasps(test, ["heightmap", "mask"], object_id=object_id)
    shape = episodes.masks.shape  # (E, G, F, H, W), in the order load_test_episodes reads them
    return episodes.replace(heightmaps=jnp.asarray(np.asarray(truth["heightmap"], np.float32).reshape(shape)),
                            masks=jnp.asarray(np.asarray(truth["mask"], bool).reshape(shape)))


def belief_rows(view: LocalizationMap, episodes, fingers: int) -> tuple[list[dict], np.ndarray]:
    """Per number of fused grasps: the share within 2 mm and the median error (symmetry-aware);
    and (E,) every episode's error after all its grasps."""
    symmetric = view.symmetries.wxyz_xyz.shape[0] > 1
    rows = []
    for result in evaluate_new_grasps(view, episodes, methods=("belief",), fingers=fingers):
        if not result.fused:
            continue
        error = result.symmetric_rmse if symmetric else result.rmse
        rows.append({"grasps": result.grasps, "within_2mm": float(np.mean(error <= 2.0)),
                     "median_rmse_mm": float(np.median(error)), "mean_p_within_2mm": float(np.mean(result.probability))})
    return rows, error


def failures(view: LocalizationMap, episodes, fingers: int, error: np.ndarray) -> list[dict]:
    """Every episode more than 2 mm off after all its grasps (``error``: (E,) from
    :func:`belief_rows` on the same map and episodes), one row each, for its worst touch (the one
    with the most contact points where the map knows no surface at the true pose): how many land
    there at the true pose and at the belief's best, and the median distance of its other points
    to the surface at the true pose; and the belief's log-likelihood at its best and at the
    truth (refined): which of the search and the likelihood missed."""
    beliefs = episode_beliefs(view, episodes, fingers=fingers, alone=False)  # (E, N): the last holds every touch
    rows = []
    for e in np.flatnonzero(error > 2.0):
        belief = jax.tree.map(lambda x: x[e, -1], beliefs)
        # The test set's sensor poses are in the object frame: the reference's pose is the truth.
        landing = {}
        for name, T_object_reference in (("truth", belief.T_world_reference), ("best", belief.best)):
            T_object_touch = T_object_reference @ belief.T_reference_touch  # (T,)
            points = jax.vmap(lambda T, p: T @ p)(T_object_touch, belief.evidence.contact)
            distance, known = (np.asarray(x) for x in view.surface.signed_distance(points))
            valid = np.asarray(belief.evidence.contact_valid & belief.touch_valid[:, None])
            landing[name] = (np.sum(valid & ~known, axis=1), np.where(valid & known, np.abs(distance), np.nan))
        worst = int(np.argmax(landing["truth"][0]))
        fit = landing["truth"][1][worst]
        best_score, truth_score = (float(x) for x in truth_against_best(view, belief, belief.T_world_reference))
        rows.append({"episode": int(e), "error_mm": float(error[e]),
                     "worst_touch_unknown_at_truth": int(landing["truth"][0][worst]),
                     "same_touch_unknown_at_best": int(landing["best"][0][worst]),
                     "worst_touch_known_fit_mm": float(np.nanmedian(fit)) if np.isfinite(fit).any() else None,
                     "contact_points_per_touch": int(belief.evidence.contact_valid.shape[1]),
                     "log_likelihood_best": best_score, "log_likelihood_truth": truth_score,
                     "missed_by": "search" if truth_score > best_score else "likelihood"})
    return rows


def add_test_set_arguments(parser: argparse.ArgumentParser) -> None:
    """A map (or ``--object`` to simulate and map), ``--test`` and ``--episodes`` of its new-grasps
    set, and the shared flags (``--quick``: 2 episodes of 2 grasps on a 20 mm map)."""
    add_map_arguments(parser)
    parser.add_argument("--test", metavar="DIR", help="new-grasps test set of the map's object (default: simulate one)")
    parser.add_argument("--episodes", type=int, default=32, help="episodes of a simulated test set (default 32)")
    add_common_arguments(parser, quick="2 episodes of 2 grasps, a 20 mm map", seed_help="a simulated test set")


def load_test_set(args: argparse.Namespace):
    """The map's view (its stored calibration), its object's name, the test set's path (simulated
    when ``--test`` is not given), its episodes and the calibration (None: the default)."""
    if args.quick:
        args.episodes = min(args.episodes, 2)
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    ((tactile_map, calibration),) = load_maps(args, model, encoder)
    name = tactile_map.object_id
    test = new_grasps_set(args, name, episodes=args.episodes, grasps=2 if args.quick else 3, fingers=2)
    episodes, _ = load_test_episodes(test, name, model, encoder, progress=False)
    return LocalizationMap.from_tactile_map(tactile_map, calibration=calibration), name, test, episodes, calibration


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_test_set_arguments(parser)
    parser.add_argument("--fingers", type=int, choices=[1, 2], default=2, help="fingers fused per grasp (default 2)")
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    view, name, test, episodes, calibration = load_test_set(args)
    distance, known = true_distance(view, name)  # once: a mesh's takes a while
    exact_view, exact_episodes = true_surface(view, distance, np.abs(distance) <= REACH_MM), exact_touches(
        episodes, test, name)
    covered_view = true_surface(view, distance, known)
    cases = {("map", "predicted"): (view, episodes), ("true, map's cells", "predicted"): (covered_view, episodes),
             ("true", "predicted"): (exact_view, episodes), ("map", "exact"): (view, exact_episodes),
             ("true", "exact"): (exact_view, exact_episodes)}
    results, errors = [], {}
    for (surface, touches), (case_view, case_episodes) in cases.items():
        print(f"surface: {surface}, touches: {touches} ...", flush=True)
        rows, errors[surface, touches] = belief_rows(case_view, case_episodes, args.fingers)
        results.append({"surface": surface, "touches": touches, "per_grasps": rows})
    grasps = [row["grasps"] for row in results[0]["per_grasps"]]
    print(format_table(
        ["surface", "touches"] + [f"{g} grasp{'s' * (g > 1)}: within 2 mm, median" for g in grasps],
        [[r["surface"], r["touches"]] + [f"{100 * row['within_2mm']:.0f} %, {row['median_rmse_mm']:.2f} mm"
                                         for row in r["per_grasps"]] for r in results]))
    failed = failures(view, episodes, args.fingers, errors["map", "predicted"])
    print(f"episodes more than 2 mm off after {grasps[-1]} grasps (the map's surface, predicted touches): "
          f"{len(failed)}")
    print(format_table(["episode", "error (mm)", "worst touch: points on unknown surface at the truth",
                        "the same touch at the belief's best", "its other points' median |distance| (mm)",
                        "log-likelihood: best, truth (refined)", "missed by"],
                       [[r["episode"], f"{r['error_mm']:.2f}",
                         f"{r['worst_touch_unknown_at_truth']} of {r['contact_points_per_touch']}",
                         r["same_touch_unknown_at_best"],
                         "-" if r["worst_touch_known_fit_mm"] is None else f"{r['worst_touch_known_fit_mm']:.2f}",
                         f"{r['log_likelihood_best']:.2f}, {r['log_likelihood_truth']:.2f}", r["missed_by"]]
                        for r in failed]))
    if failed:
        search = sum(r["missed_by"] == "search" for r in failed)
        print(f"missed by the search (the truth scores higher than the best): {search} of {len(failed)}; by the "
              f"likelihood (the best scores higher): {len(failed) - search}")
    share = coverage(distance, known)
    print(f"{name}: {episodes.openings.shape[0]} episodes x {args.fingers} finger(s); calibration: "
          f"{'stored' if calibration is not None else 'none (default)'}; the map knows {100 * share:.0f} % of the "
          f"object's surface")
    if args.json:
        write_json(args.json, {"object": name, "map": (map_paths(args) or [name])[0], "test": str(test),
                               "fingers": args.fingers, "episodes": int(episodes.openings.shape[0]),
                               "coverage": share, "results": results, "failures": failed, "seed": args.seed,
                               "machine": machine_info()})
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
