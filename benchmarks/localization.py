"""The paper's CTI-ICP-N per touch: speed and accuracy against Open3D's ICP in the same run (issue 5).

One map of >= 500 imprints (default: the YCB scissors on the paper's 10 mm protocol). Each
stage of a touch is timed on its own after compilation (steady-state median over ``--repeats``
touches, compile time reported apart):

- heightmap prediction (the bundled shape model), features (the encoder), retrieval (CTI top-N
  by cosine similarity among openings within 2 mm), registration (pure-JAX point-to-plane ICP);
- the reference: the same retrieval, then Open3D's point-to-plane ICP of the query cloud against
  the union of the N retrieved imprints' clouds, started at the closest one (the paper's
  CTI-ICP-N with a peer library), on the same queries and points.

Recompilations across the ``--repeats`` localizations are counted (jax's compile log) and must be
zero. Accuracy: leave-one-out median cloud RMSE (mm) of both pipelines on the same queries.

    python benchmarks/localization.py --json localization_speed.json
    python benchmarks/localization.py --quick --no-open3d    # smoke run: 20 calls, 10 queries, 20 mm map

Needs the ``benchmark`` extra (``open3d-cpu``), which imports only with the Debian package
``libusb-1.0-0`` installed (``apt-get install libusb-1.0-0``). ``--no-open3d`` leaves the
reference out (e.g. on a GPU machine without it; so does a missing Open3D); the JAX figures are
the same.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from tactojax import CompilationCounter
from tactojax.features import encode_image
from tactojax.io import resolve_encoder, resolve_shape_model
# The stages of the baseline, timed apart and handed to Open3D:
from tactojax.localize import LocalizationMap
from tactojax.localize.baselines import IcpSettings, closest_imprints, contact_points, estimate_pose, localize_baseline
from tactojax.localize.evaluation import map_touch
from tactojax.shape import predict

try:  # run as ``python benchmarks/localization.py`` or as a module
    from benchmarks._common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                                    write_json)
except ImportError:
    from _common import add_common_arguments, add_map_arguments, format_table, load_maps, machine_info, write_json


def timed(function, calls: int) -> tuple[float, float]:
    """(first-call seconds incl. compilation, steady-state median seconds) of ``function()``."""
    start = time.perf_counter()
    jax.block_until_ready(function())
    first = time.perf_counter() - start
    times = []
    for _ in range(calls):
        start = time.perf_counter()
        jax.block_until_ready(function())
        times.append(time.perf_counter() - start)
    return first, float(np.median(times))


def open3d_register(o3d, source_points, target_points, target_normals, T_init, *, max_distance_mm, iterations):
    """Open3D point-to-plane ICP: the query cloud (sensor frame) onto the target (object frame)."""
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source_points.astype(np.float64)))
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target_points.astype(np.float64)))
    target.normals = o3d.utility.Vector3dVector(target_normals.astype(np.float64))
    result = o3d.pipelines.registration.registration_icp(
        source, target, max_distance_mm, T_init,
        o3d.pipelines.registration.TransformationEstimationPointToPlane(),
        o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=iterations))
    return result.transformation


def cloud_rmse(points: np.ndarray, T_true: np.ndarray, T_estimate: np.ndarray) -> float:
    """RMSE (mm) between a cloud placed at the true and at the estimated pose."""
    homogeneous = np.concatenate([points, np.ones((len(points), 1))], axis=1)
    difference = homogeneous @ (T_true - T_estimate).T
    return float(np.sqrt(np.mean(np.sum(difference[:, :3] ** 2, axis=1))))


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_map_arguments(parser)
    parser.add_argument("--n", type=int, default=5, help="N of CTI-ICP-N (default 5)")
    parser.add_argument("--queries", type=int, default=200, help="leave-one-out queries for accuracy")
    parser.add_argument("--no-open3d", action="store_true", help="leave out the Open3D reference pipeline")
    add_common_arguments(parser, quick="20 timed localizations, 10 accuracy queries, a 20 mm map",
                         seed_help="the touches timed and queried", repeats=1000,
                         repeats_help="timed localizations, each a different touch")
    args = parser.parse_args()
    if args.quick:
        args.repeats, args.queries = min(args.repeats, 20), min(args.queries, 10)
    return args


class Stages:
    """The baseline's steps on one map, each jitted on its own: retrieval, contact points, registration."""

    def __init__(self, view: LocalizationMap, n: int, settings: IcpSettings):
        method = f"cti-icp-{n}"
        self.retrieve = jax.jit(lambda q, exclude: closest_imprints(
            view.features, view.openings, view.imprint_valid, q.feature, q.opening, n, exclude=exclude))
        self.sample = jax.jit(lambda q: contact_points(q, view.mm_per_px))
        self.register = jax.jit(lambda p, pv, i, iv: estimate_pose(view, p, pv, i, iv, method, settings=settings))


def stage_timings(model, encoder, tactile_map, view, stages: Stages, index: int) -> dict:
    """(first call incl. compile, steady median) seconds of every stage on imprint ``index``."""
    image = jnp.asarray(tactile_map.stored_images()[index], jnp.float32) / 255.0
    query = map_touch(view, index)
    timings = {"heightmap": timed(lambda: predict(model, image), 50),
               "features": timed(lambda: encode_image(encoder, image), 50),
               "retrieval": timed(lambda: stages.retrieve(query, 0), 200)}  # its first call compiles
    indices, _, index_valid = stages.retrieve(query, index)
    points, points_valid = stages.sample(query)
    timings["registration"] = timed(lambda: stages.register(points, points_valid, indices, index_valid), 200)
    return timings


def end_to_end(view, method: str, order: np.ndarray, key) -> tuple[float, int]:
    """Retrieval + registration of many different touches (each taken from the map first: the
    timed call is what a control loop runs once it has them): median ms, recompilations."""
    def one_touch(call, touch, index):
        return localize_baseline(jax.random.fold_in(key, call), view, touch, method=method, exclude=int(index))

    jax.block_until_ready(one_touch(0, map_touch(view, int(order[0])), order[0]))  # compile
    times = []
    with CompilationCounter() as counter:
        for call, index in tqdm(list(enumerate(order)), desc="localize", unit="touch"):
            touch = jax.block_until_ready(map_touch(view, int(index)))
            start = time.perf_counter()
            jax.block_until_ready(one_touch(call, touch, index))
            times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times)), counter.count


def accuracy(o3d, tactile_map, view, stages: Stages, method: str, queries: np.ndarray, settings: IcpSettings,
             key) -> dict:
    """The same leave-one-out queries through tactojax and (``o3d`` not None) the same retrieval
    and points into Open3D's ICP: cloud RMSE (mm) and seconds per query of each."""
    points_object, normals_object = np.asarray(tactile_map.points_object), np.asarray(tactile_map.normals_object)
    point_valid = np.asarray(tactile_map.point_valid)
    T_all = np.asarray(tactile_map.T_object_sensor.as_matrix())
    out = {"jax_errors": [], "o3d_errors": [], "o3d_times": []}
    for index in queries:
        touch = map_touch(view, int(index))
        estimate = jax.block_until_ready(localize_baseline(key, view, touch, method=method, exclude=int(index)))
        cloud = np.asarray(tactile_map.points[index])[np.asarray(tactile_map.valid[index])]
        out["jax_errors"].append(cloud_rmse(cloud, T_all[index], np.asarray(estimate.T_object_sensor.as_matrix())))
        if o3d is None:
            continue
        start = time.perf_counter()
        top, _, top_valid = jax.device_get(stages.retrieve(touch, int(index)))
        p, pv = jax.device_get(stages.sample(touch))  # the points localize() uses (a fixed pixel order)
        chosen = top[top_valid]
        if len(chosen) == 0:
            out["o3d_times"].append(time.perf_counter() - start)
            out["o3d_errors"].append(np.nan)
            continue
        mask = point_valid[chosen].reshape(-1)
        T_estimate = open3d_register(o3d, p[pv], points_object[chosen].reshape(-1, 3)[mask],
                                     normals_object[chosen].reshape(-1, 3)[mask], T_all[chosen[0]],
                                     max_distance_mm=settings.max_distance_mm, iterations=settings.iterations)
        out["o3d_times"].append(time.perf_counter() - start)
        out["o3d_errors"].append(cloud_rmse(cloud, T_all[index], T_estimate))
    return out


def print_results(result: dict) -> None:
    print("\nstage timings (ms): first call incl. compile, steady-state median")
    print(format_table(["stage", "first call", "steady median"],
                       [[stage, f"{t['first_incl_compile']:.0f}", f"{t['steady_median']:.2f}"]
                        for stage, t in result["stages_ms"].items()]))
    rows = [["tactojax (JAX)", result["tactojax_ms_per_touch"], result["tactojax_median_rmse_mm"],
             result["recompilations"]]]
    if result["open3d_ms_per_touch"] is not None:
        rows.append(["Open3D ICP", result["open3d_ms_per_touch"], result["open3d_median_rmse_mm"], "-"])
    print(f"\n{result['method'].upper()}, retrieval + registration per touch, {result['calls']} calls:")
    print(format_table(["pipeline", "ms per touch", "median RMSE (mm)", "recompilations"], rows))
    if result["speedup"] is not None:
        print(f"speed-up over Open3D: {result['speedup']:.1f}x")


def main() -> None:
    args = parse_args()
    o3d = None
    if not args.no_open3d:
        try:
            import open3d as o3d  # benchmark-only dependency
        except ImportError as error:
            print(f"Open3D reference left out: {error}")
    print(f"JAX backend: {jax.default_backend()} ({jax.devices()[0].device_kind})")
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    ((tactile_map, _),) = load_maps(args, model, encoder, images=True)  # the stage timings start from an image
    view, settings, method = LocalizationMap.from_tactile_map(tactile_map), IcpSettings(), f"cti-icp-{args.n}"
    valid = np.flatnonzero(np.asarray(tactile_map.imprint_valid))
    print(f"map: {tactile_map.object_id}, {len(tactile_map)} imprints ({len(valid)} with contact)")
    rng, key, stages = np.random.default_rng(args.seed), jax.random.key(args.seed), Stages(view, args.n, settings)
    order = rng.choice(valid, size=args.repeats, replace=True)
    timings = stage_timings(model, encoder, tactile_map, view, stages, int(order[0]))
    jax_ms, recompilations = end_to_end(view, method, order, key)
    queries = rng.choice(valid, size=min(args.queries, len(valid)), replace=False)
    errors = accuracy(o3d, tactile_map, view, stages, method, queries, settings, key)
    o3d_ms = None if o3d is None else 1e3 * float(np.median(errors["o3d_times"]))
    result = {
        "map": {"object": tactile_map.object_id, "imprints": len(tactile_map), "with_contact": int(len(valid))},
        "method": method, "calls": args.repeats, "recompilations": recompilations,
        "stages_ms": {s: {"first_incl_compile": 1e3 * f, "steady_median": 1e3 * m} for s, (f, m) in timings.items()},
        "tactojax_ms_per_touch": jax_ms, "open3d_ms_per_touch": o3d_ms,
        "speedup": None if o3d_ms is None else o3d_ms / jax_ms,
        "tactojax_median_rmse_mm": float(np.nanmedian(errors["jax_errors"])),
        "open3d_median_rmse_mm": None if o3d is None else float(np.nanmedian(errors["o3d_errors"])),
        "accuracy_queries": int(len(queries)), "seed": args.seed,
        "machine": {**machine_info(), "open3d": None if o3d is None else o3d.__version__},
    }
    print_results(result)
    if args.json:
        write_json(args.json, result)
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
