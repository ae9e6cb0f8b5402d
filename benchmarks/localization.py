"""The paper's CTI-ICP-N per touch: speed and accuracy against Open3D's ICP in the same run (issue 5).

One map of >= 500 imprints (default: the YCB scissors on the paper's 10 mm protocol). Each
stage of a touch is timed on its own after compilation (steady-state median over ``--calls``
touches, compile time reported apart):

- heightmap prediction (the bundled shape model), features (the encoder), retrieval (CTI top-N
  by cosine similarity among openings within 2 mm), registration (pure-JAX point-to-plane ICP);
- the reference: the same retrieval, then Open3D's point-to-plane ICP of the query cloud against
  the union of the N retrieved imprints' clouds, started at the closest one (the paper's
  CTI-ICP-N with a peer library), on the same queries and points.

Recompilations across the ``--calls`` localizations are counted (jax's compile log) and must be
zero. Accuracy: leave-one-out median cloud RMSE (mm) of both pipelines on the same queries.

    python benchmarks/localization.py --json localization_speed.json

Needs the ``benchmark`` extra (``open3d-cpu``), which imports only with the Debian package
``libusb-1.0-0`` installed (``apt-get install libusb-1.0-0``). ``--no-open3d`` leaves the
reference out (e.g. on a GPU machine without it); the JAX figures are the same.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from tactojax._compilation import CompilationCounter
from tactojax.features import encode_image, encode_images
from tactojax.io import DEFAULT_ENCODER, load_tactile_map, resolve_encoder, resolve_shape_model, read_grasps
from tactojax.localize import IcpSettings, LocalizationMap, localize_baseline
# The stages of the baseline, timed apart and handed to Open3D (not the public API):
from tactojax.localize._baselines import estimate_pose, parse_method
from tactojax.localize._map import map_touch
from tactojax.localize._points import contact_points
from tactojax.localize._retrieval import closest_imprints
from tactojax.mapping import build_tactile_map
from tactojax.objects import get_object
from tactojax.sensor import gelslim
from tactojax.shape import predict
from tactojax.simulate import MappingProtocol, simulate_to_dataset

try:  # run as ``python benchmarks/localization.py`` or as a module
    from benchmarks._common import machine_info, write_json
except ImportError:
    from _common import machine_info, write_json


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


def build_map(work: Path, name: str, model, encoder):
    """Simulate (once) and map one object, with features."""
    path = work / f"{name}-grid10-gelslim0.5"
    if not (path / "manifest.json").exists():
        simulate_to_dataset(path, jax.random.key(0), gelslim(scale=0.5), get_object(name), MappingProtocol())
    grasps = read_grasps(path)
    tactile_map = build_tactile_map(model, grasps["images"], grasps["T_world_gripper"], grasps["openings"], name,
                                    T_world_object=grasps["T_world_object"])
    return tactile_map.with_features(encode_images(encoder, tactile_map.stored_images(), progress=True))


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--map", help="a saved map with >= 500 imprints (default: simulate and map --object)")
    parser.add_argument("--object", default="scissors")
    parser.add_argument("--work", default="benchmark-data/localization", help="simulated data cache")
    parser.add_argument("--model", default="bundled:fast-gelslim-0.5")
    parser.add_argument("--encoder", default=DEFAULT_ENCODER, help="feature encoder (default: the CLI's)")
    parser.add_argument("--n", type=int, default=5, help="N of CTI-ICP-N (default 5)")
    parser.add_argument("--calls", type=int, default=1000, help="timed localizations (default 1000)")
    parser.add_argument("--queries", type=int, default=200, help="leave-one-out queries for accuracy")
    parser.add_argument("--json", metavar="PATH")
    parser.add_argument("--no-open3d", action="store_true", help="leave out the Open3D reference pipeline")
    args = parser.parse_args()
    o3d = None
    if not args.no_open3d:
        import open3d as o3d  # benchmark-only dependency
    print(f"JAX backend: {jax.default_backend()} ({jax.devices()[0].device_kind})")

    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    if args.map:
        tactile_map = load_tactile_map(args.map, images=True)
        if tactile_map.features.shape[1] == 0:
            tactile_map = tactile_map.with_features(encode_images(encoder, tactile_map.stored_images(), progress=True))
    else:
        tactile_map = build_map(Path(args.work), args.object, model, encoder)
    view = LocalizationMap.from_tactile_map(tactile_map)
    valid = np.flatnonzero(np.asarray(tactile_map.imprint_valid))
    print(f"map: {tactile_map.object_id}, {len(tactile_map)} imprints ({len(valid)} with contact)")
    method = parse_method(f"cti-icp-{args.n}")
    settings = IcpSettings()
    rng = np.random.default_rng(0)
    order = rng.choice(valid, size=args.calls, replace=True)
    image = jnp.asarray(tactile_map.stored_images()[int(order[0])], jnp.float32) / 255.0
    query = map_touch(view, int(order[0]))
    key = jax.random.key(0)

    # Stage timings, each jitted function on its own.
    stages = {}
    stages["heightmap"] = timed(lambda: predict(model, image), 50)
    stages["features"] = timed(lambda: encode_image(encoder, image), 50)
    retrieve = jax.jit(lambda q, exclude: closest_imprints(view.features, view.openings, view.imprint_valid,
                                                           q.feature, q.opening, args.n, exclude=exclude))
    stages["retrieval"] = timed(lambda: retrieve(query, 0), 200)
    indices, _, index_valid = retrieve(query, int(order[0]))
    sample = jax.jit(lambda q: contact_points(q, view.mm_per_px))
    points, points_valid = sample(query)
    register = jax.jit(lambda p, pv, i, iv: estimate_pose(view, p, pv, i, iv, method, settings=settings))
    stages["registration"] = timed(lambda: register(points, points_valid, indices, index_valid), 200)

    # End to end (retrieval + registration), many different touches, counting recompilations.
    # Each touch (heightmap, mask, features, opening) is taken from the map first: the timed
    # call is what a control loop runs once it has them.
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
    jax_ms = 1e3 * float(np.median(times))

    # Same queries through both pipelines: accuracy and Open3D's time.
    queries = rng.choice(valid, size=min(args.queries, len(valid)), replace=False)
    points_object, normals_object = np.asarray(tactile_map.points_object), np.asarray(tactile_map.normals_object)
    point_valid = np.asarray(tactile_map.point_valid)
    T_all = np.asarray(tactile_map.T_object_sensor.as_matrix())
    jax_errors, o3d_errors, o3d_times, jax_times = [], [], [], []
    for index in queries:
        touch = map_touch(view, int(index))
        start = time.perf_counter()
        estimate = jax.block_until_ready(localize_baseline(key, view, touch, method=method, exclude=int(index)))
        jax_times.append(time.perf_counter() - start)
        cloud = np.asarray(tactile_map.points[index])[np.asarray(tactile_map.valid[index])]
        jax_errors.append(cloud_rmse(cloud, T_all[index], np.asarray(estimate.T_object_sensor.as_matrix())))
        if o3d is None:
            continue
        # Open3D pipeline: the same retrieval and query points, then Open3D ICP.
        start = time.perf_counter()
        top, _, top_valid = jax.device_get(retrieve(touch, int(index)))
        p, pv = jax.device_get(sample(touch))  # the points localize() uses (a fixed pixel order)
        chosen = top[top_valid]
        if len(chosen) == 0:
            o3d_times.append(time.perf_counter() - start)
            o3d_errors.append(np.nan)
            continue
        mask = point_valid[chosen].reshape(-1)
        T_estimate = open3d_register(o3d, p[pv], points_object[chosen].reshape(-1, 3)[mask],
                                     normals_object[chosen].reshape(-1, 3)[mask], T_all[chosen[0]],
                                     max_distance_mm=settings.max_distance_mm, iterations=settings.iterations)
        o3d_times.append(time.perf_counter() - start)
        o3d_errors.append(cloud_rmse(cloud, T_all[index], T_estimate))

    rows = [[stage, f"{1e3 * first:.0f}", f"{1e3 * steady:.2f}"] for stage, (first, steady) in stages.items()]
    print("\nstage timings (ms): first call incl. compile, steady-state median")
    for row in rows:
        print(f"  {row[0]:<14}{row[1]:>10}{row[2]:>10}")
    jax_median = float(np.nanmedian(jax_errors))
    print(f"\nCTI-ICP-{args.n}, retrieval + registration per touch, {args.calls} calls:")
    print(f"  tactojax (JAX)   {jax_ms:7.2f} ms   median RMSE {jax_median:6.2f} mm   recompilations {counter.count}")
    o3d_ms = o3d_median = None
    if o3d is not None:
        o3d_median, o3d_ms = float(np.nanmedian(o3d_errors)), 1e3 * float(np.median(o3d_times))
        print(f"  Open3D ICP       {o3d_ms:7.2f} ms   median RMSE {o3d_median:6.2f} mm")
        print(f"  speed-up         {o3d_ms / jax_ms:7.1f}x")
    if args.json:
        result = {
            "map": {"object": tactile_map.object_id, "imprints": len(tactile_map), "with_contact": int(len(valid))},
            "method": method.name, "calls": args.calls, "recompilations": counter.count,
            "stages_ms": {s: {"first_incl_compile": 1e3 * f, "steady_median": 1e3 * m} for s, (f, m) in stages.items()},
            "tactojax_ms_per_touch": jax_ms, "open3d_ms_per_touch": o3d_ms,
            "speedup": None if o3d_ms is None else o3d_ms / jax_ms,
            "tactojax_median_rmse_mm": jax_median, "open3d_median_rmse_mm": o3d_median,
            "accuracy_queries": int(len(queries)),
            "machine": {**machine_info(), "open3d": None if o3d is None else o3d.__version__},
        }
        write_json(args.json, result)
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
