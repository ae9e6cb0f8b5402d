"""What limits single-touch localization on a map: retrieval, registration, or the touch itself?

For leave-one-out queries of each map (issue 5's <= 2 mm target), this separates three causes:

- **retrieval**: how often the N most similar imprints (CTI: cosine similarity of features,
  openings within 2 mm) include a true neighbour, an imprint whose pose is within 3 mm (cloud
  RMSE) of the best any stored imprint offers (``recall@N``);
- **registration**: cti-search-N started from the truly nearest imprints instead (oracle
  retrieval): what the search and ICP reach when retrieval is perfect;
- **ambiguity**: for every cti-search-N estimate more than 5 mm off, whether the map supports
  it at least as well as the true pose (:func:`~tactojax.localize.verification_score`, the
  check that picks the search's winner). Such a touch fits two places on the object equally
  well, so no choice among the hypotheses can be trusted to find the right one.

    python benchmarks/localization_ceiling.py scissors.npz screwdriver.npz --queries 200 --json ceiling.json

Maps without features are encoded with ``--encoder`` first (the CLI default).
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from tqdm.auto import tqdm

from tactojax.features import encode_images
from tactojax.io import DEFAULT_ENCODER, load_tactile_map, resolve_encoder
from tactojax.localize import (
    LocalizationMap, SearchSettings, closest_imprints, cloud_moments, cloud_rmse, evaluate_localization, localize,
    map_query, moment_rmse, oracle_imprints, query_points, verification_score,
)

try:  # run as ``python benchmarks/localization_ceiling.py`` or as a module
    from benchmarks._common import format_table, machine_info, write_json
except ImportError:
    from _common import format_table, machine_info, write_json

NEAR_MM = 3.0
"""A retrieved imprint is a true neighbour within this of the best stored pose (cloud RMSE), mm."""
WRONG_MM = 5.0
"""An estimate further off than this (cloud RMSE) counts as a wrong place, mm."""


def pose_rmse_to_every_imprint(tactile_map, view: LocalizationMap, query: int) -> np.ndarray:
    """(K,) cloud RMSE (mm) of the query's cloud at every stored imprint's pose against its true pose."""
    T_all = view.T_object_sensor
    T_true = jaxlie.SE3(T_all.wxyz_xyz[query])
    points, valid = tactile_map.points[query], tactile_map.valid[query]
    return np.asarray(moment_rmse(*cloud_moments(points, valid), T_true, T_all))


def retrieved_near(tactile_map, view: LocalizationMap, index: int, retrieve: int) -> np.ndarray:
    """(retrieve,) bool: which of the ``retrieve`` most similar imprints (CTI, query ``index``
    left out) are true neighbours, their pose within ``NEAR_MM`` of the best stored pose (cloud RMSE)."""
    query = map_query(view, index)
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


def ceiling(tactile_map, n: int, queries: np.ndarray, recall_at=(1, 5, 15, 50)) -> dict:
    """The three diagnostics of the module docstring for one map (a JSON-ready dict)."""
    view = LocalizationMap.from_tactile_map(tactile_map)
    count = len(view)
    settings = SearchSettings()
    method = f"cti-search-{n}"
    retrieve = min(max(recall_at), count)

    @jax.jit
    def scores(query, exclude, T_estimate, T_true):
        points, points_valid = query_points(query, view.mm_per_px)
        available = view.imprint_valid & (jnp.arange(count) != exclude)
        def score(T):
            return verification_score(view, query.heightmap, query.mask, points, points_valid, T, available, settings)
        return score(T_estimate), score(T_true)

    has_near = {k: [] for k in recall_at}
    errors, ambiguous = [], []
    key = jax.random.key(0)
    for index in tqdm(queries.tolist(), desc=f"{tactile_map.object_id} {method}", unit="touch"):
        query = map_query(view, index)
        near = retrieved_near(tactile_map, view, index, retrieve)
        T_true = jaxlie.SE3(view.T_object_sensor.wxyz_xyz[index])
        for k in recall_at:
            has_near[k].append(bool(near[:k].any()))
        estimate = localize(key, view, query, method=method, exclude=index)
        error = float(cloud_rmse(tactile_map.points[index], tactile_map.valid[index], T_true, estimate.T_object_sensor))
        errors.append(error)
        if error > WRONG_MM:
            at_estimate, at_truth = jax.device_get(scores(query, index, estimate.T_object_sensor, T_true))
            ambiguous.append(bool(at_estimate >= at_truth))
    oracle = evaluate_localization(key, tactile_map, [method], queries=queries, oracle=True)[method]
    errors = np.asarray(errors)
    return {
        "object": tactile_map.object_id, "queries": len(queries), "method": method,
        "recall": {str(k): float(np.mean(v)) for k, v in has_near.items()},
        "median_rmse_mm": float(np.median(errors)), "within_2mm": float(np.mean(errors <= 2.0)),
        "oracle_median_rmse_mm": float(np.median(oracle.rmse)), "oracle_within_2mm": float(np.mean(oracle.rmse <= 2.0)),
        "wrong": len(ambiguous), "wrong_fitting_as_well_as_truth": float(np.mean(ambiguous)) if ambiguous else 0.0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("maps", nargs="+", help="saved maps (.npz)")
    parser.add_argument("--encoder", default=DEFAULT_ENCODER, help="for maps without features (default: the CLI's)")
    parser.add_argument("--n", type=int, default=5, help="N of cti-search-N (default 5)")
    parser.add_argument("--queries", type=int, default=200, help="leave-one-out queries per map (default 200)")
    parser.add_argument("--json", metavar="PATH")
    args = parser.parse_args()

    results = []
    for path in args.maps:
        tactile_map = load_tactile_map(path)
        if tactile_map.features.shape[1] == 0:
            tactile_map = tactile_map.with_features(encode_images(resolve_encoder(args.encoder), tactile_map.images,
                                                                  progress=True))
        valid = np.flatnonzero(np.asarray(tactile_map.imprint_valid))
        queries = np.sort(np.random.default_rng(0).choice(valid, size=min(args.queries, len(valid)), replace=False))
        results.append(ceiling(tactile_map, args.n, queries))

    recall_keys = list(results[0]["recall"])
    headers = (["object", "queries"] + [f"recall@{k}" for k in recall_keys]
               + [f"cti-search-{args.n}: median, <= 2 mm", "oracle retrieval: median, <= 2 mm",
                  "wrong estimates that fit as well as the truth"])
    rows = [[r["object"], r["queries"]] + [f"{100 * r['recall'][k]:.0f} %" for k in recall_keys]
            + [f"{r['median_rmse_mm']:.1f} mm, {100 * r['within_2mm']:.0f} %",
               f"{r['oracle_median_rmse_mm']:.2f} mm, {100 * r['oracle_within_2mm']:.0f} %",
               f"{100 * r['wrong_fitting_as_well_as_truth']:.0f} % of {r['wrong']}"] for r in results]
    print(format_table(headers, rows))
    if args.json:
        write_json(args.json, {"results": results, "near_mm": NEAR_MM, "wrong_mm": WRONG_MM,
                               "machine": machine_info()})
        print(f"wrote {args.json}")

if __name__ == "__main__":
    main()
