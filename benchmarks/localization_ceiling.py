"""What limits single-touch localization on a map: retrieval, registration, or the touch itself?

For leave-one-out queries of each map (issue 5's <= 2 mm target), this separates three causes:

- **retrieval**: how often the N most similar imprints (CTI: cosine similarity of features,
  openings within 2 mm) include a true neighbour, an imprint whose pose is within 3 mm (cloud
  RMSE) of the best any stored imprint offers (``recall@N``);
- **registration**: the paper's CTI-ICP-N with retrieval as it is and started from the truly
  nearest imprints instead (oracle retrieval): what ICP reaches when retrieval is perfect;
- **ambiguity**: the pose belief (:func:`~tactojax.localize.localize`, its queries held out of
  the map's surface fold by fold) over the same queries, and for every belief more than 5 mm
  off, whether it *knew*: a touch that fits two places on the object equally well cannot be
  localized by any choice among the hypotheses, but a calibrated belief then says so (a low
  P(within 2 mm)); a wrong belief with P(within 2 mm) > 0.5 is a confident mistake.

Errors are the paper's cloud RMSE up to the object's symmetry (the catalog's). A map's stored
belief calibration (``tactojax calibrate-belief``) is used when it has one.

    python benchmarks/localization_ceiling.py scissors.npz screwdriver.npz --queries 200 --json ceiling.json
    python benchmarks/localization_ceiling.py --quick   # smoke run: 10 queries, 2 folds, scissors on a 20 mm map

Maps are encoded with ``--encoder`` (the CLI default) unless they store its features; without a
map, ``--object`` is simulated and mapped.
"""

from __future__ import annotations

import argparse

import jax
import jaxlie
import numpy as np
from tqdm.auto import tqdm

from tactojax.io import resolve_encoder, resolve_shape_model
# Retrieval and the oracle's nearest imprints, looked at apart:
from tactojax.localize import LocalizationMap
from tactojax.localize.baselines import closest_imprints
from tactojax.localize.evaluation import cloud_moments, evaluate_localization, map_touch, moment_rmse, oracle_imprints

try:  # run as ``python benchmarks/localization_ceiling.py`` or as a module
    from benchmarks._common import add_common_arguments, add_map_arguments, format_table, load_maps, machine_info, write_json
except ImportError:
    from _common import add_common_arguments, add_map_arguments, format_table, load_maps, machine_info, write_json

NEAR_MM = 3.0
"""A retrieved imprint is a true neighbour within this of the best stored pose (cloud RMSE), mm."""
WRONG_MM = 5.0
"""An estimate further off than this (cloud RMSE) counts as a wrong place, mm."""
SURE = 0.5
"""A wrong belief with P(within 2 mm) above this was a confident mistake."""


def pose_rmse_to_every_imprint(tactile_map, view: LocalizationMap, query: int) -> np.ndarray:
    """(K,) cloud RMSE (mm) of the query's cloud at every stored imprint's pose against its true pose."""
    T_all = view.T_object_sensor
    T_true = jaxlie.SE3(T_all.wxyz_xyz[query])
    points, valid = tactile_map.points[query], tactile_map.valid[query]
    return np.asarray(moment_rmse(*cloud_moments(points, valid), T_true, T_all))


def retrieved_near(tactile_map, view: LocalizationMap, index: int, retrieve: int) -> np.ndarray:
    """(retrieve,) bool: which of the ``retrieve`` most similar imprints (CTI, query ``index``
    left out) are true neighbours, their pose within ``NEAR_MM`` of the best stored pose (cloud RMSE)."""
    query = map_touch(view, index)
    rmse = pose_rmse_to_every_imprint(tactile_map, view, index)
    indices, _, valid = jax.device_get(closest_imprints(view.features, view.openings, view.imprint_valid,
                                                        query.feature, query.opening, retrieve, exclude=index))
    T_true = jaxlie.SE3(view.T_object_sensor.wxyz_xyz[index])
    # The best pose any retrievable imprint offers: oracle retrieval's first choice.
    nearest, nearest_valid = jax.device_get(oracle_imprints(
        view, tactile_map.points[index], tactile_map.valid[index], T_true, query.opening, 1, exclude=index))
    best = rmse[nearest[0]] if nearest_valid[0] else np.inf
    return (rmse[indices] <= best + NEAR_MM) & valid


def retrieval_recall(tactile_map, queries: np.ndarray, recall_at=(1, 5, 15, 50), *, progress: bool = True) -> dict:
    """``{str(N): recall@N}``: the share of ``queries`` whose N most similar imprints hold a true
    neighbour (:func:`retrieved_near`); the map's features decide the ranking."""
    view = LocalizationMap.from_tactile_map(tactile_map)
    retrieve = min(max(recall_at), len(view))
    has_near = {k: [] for k in recall_at}
    for index in tqdm(queries.tolist(), desc=f"{tactile_map.object_id} recall", unit="touch", disable=not progress):
        near = retrieved_near(tactile_map, view, index, retrieve)
        for k in recall_at:
            has_near[k].append(bool(near[:k].any()))
    return {str(k): float(np.mean(v)) for k, v in has_near.items()}


def ceiling(tactile_map, n: int, queries: np.ndarray, recall_at=(1, 5, 15, 50), *, calibration=None,
            folds: int = 10, seed: int = 0) -> dict:
    """The three diagnostics of the module docstring for one map (a JSON-ready dict)."""
    key = jax.random.key(seed)
    method = f"cti-icp-{n}"
    recall = retrieval_recall(tactile_map, queries, recall_at)
    results = evaluate_localization(key, tactile_map, [method, "belief"], calibration=calibration, queries=queries,
                                    folds=folds, progress=True)
    oracle = evaluate_localization(key, tactile_map, [method], queries=queries, oracle=True, progress=True)[method]
    registered, belief = results[method], results["belief"]
    wrong = belief.symmetric_rmse > WRONG_MM

    def stats(errors):
        return {"median_rmse_mm": float(np.median(errors)), "within_2mm": float(np.mean(errors <= 2.0))}

    return {
        "object": tactile_map.object_id, "queries": len(queries), "method": method, "recall": recall,
        "registration": stats(registered.symmetric_rmse), "oracle_registration": stats(oracle.symmetric_rmse),
        "belief": {**stats(belief.symmetric_rmse), "mean_p_within_2mm": float(np.mean(belief.probability))},
        "belief_wrong": int(wrong.sum()),
        "belief_wrong_but_sure": float(np.mean(belief.probability[wrong] > SURE)) if wrong.any() else 0.0,
    }


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_map_arguments(parser, several=True)
    parser.add_argument("--n", type=int, default=5, help="N of CTI-ICP-N (default 5)")
    parser.add_argument("--folds", type=int, default=10, help="the belief's queries are held out of the map's "
                                                               "surface in this many folds (default 10)")
    parser.add_argument("--queries", type=int, default=200, help="leave-one-out queries per map (default 200)")
    add_common_arguments(parser, quick="10 queries, 2 folds, a 20 mm map", seed_help="query choice and keys")
    args = parser.parse_args()
    if args.quick:
        args.queries, args.folds = min(args.queries, 10), min(args.folds, 2)
    return args


def print_results(args, results: list[dict]) -> None:
    recall_keys = list(results[0]["recall"])

    def cell(entry):
        return f"{entry['median_rmse_mm']:.2f} mm, {100 * entry['within_2mm']:.0f} %"

    headers = (["object", "queries"] + [f"recall@{k}" for k in recall_keys]
               + [f"CTI-ICP-{args.n}: median, <= 2 mm", "oracle retrieval: median, <= 2 mm",
                  "belief: median, <= 2 mm", f"wrong beliefs (> {WRONG_MM:g} mm) with P > {SURE:g}"])
    rows = [[r["object"], r["queries"]] + [f"{100 * r['recall'][k]:.0f} %" for k in recall_keys]
            + [cell(r["registration"]), cell(r["oracle_registration"]), cell(r["belief"]),
               f"{100 * r['belief_wrong_but_sure']:.0f} % of {r['belief_wrong']}"] for r in results]
    print(format_table(headers, rows))
    print("errors: cloud RMSE up to the object's symmetry")


def main() -> None:
    args = parse_args()
    model = None if args.maps else resolve_shape_model(args.model)  # only to map --object
    results = []
    for tactile_map, calibration in load_maps(args, model, resolve_encoder(args.encoder)):
        valid = np.flatnonzero(np.asarray(tactile_map.imprint_valid))
        queries = np.sort(np.random.default_rng(args.seed).choice(valid, size=min(args.queries, len(valid)),
                                                                  replace=False))
        results.append(ceiling(tactile_map, args.n, queries, calibration=calibration, folds=args.folds,
                               seed=args.seed))
    print_results(args, results)
    if args.json:
        write_json(args.json, {"results": results, "near_mm": NEAR_MM, "wrong_mm": WRONG_MM, "sure": SURE,
                               "seed": args.seed, "machine": machine_info()})
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
