"""The whole touch on a CPU: frame in, identity and pose out, per stage, beside a peer pipeline (issue 17).

One run, one process, the same touches (new grasps at yaw 10 deg, not in the map, as in
``benchmarks/live.py``):

- **tactojax**, each stage jitted on its own (heightmap: ``predict`` + ``observed_contact``;
  features: the encoder; the pose belief of the touch, :func:`~tactojax.localize.update_belief`;
  and the paper's identification + CTI-ICP-N, as the peer runs it), then the deployed path: the
  live ``Localizer`` fusing each touch as a grasp (``fuse``: frame and gripper pose in, belief
  out), and a frame that updates nothing (a grasp still settling). Per stage: the steady-state
  median, the kernels the compiled program launches (``kernel_count``) and its compile time.
  Recompilations in the loop are counted (must be 0).
- **the peer** (``benchmarks/_peer.py``): the same two networks exported to ONNX and run by ONNX
  Runtime, NumPy/SciPy/OpenCV around them, Open3D's point-to-plane ICP.
- **the floor**: the networks' floating-point operations (XLA's cost analysis of the compiled
  stages) over what this machine's CPU sustains on a large matrix product.

Accuracy: the median position error of both pipelines against the simulator's truth (the
Localizer's belief from one touch, the peer's CTI-ICP-N).

    python benchmarks/whole_touch.py --json whole_touch.json

Needs the ``benchmark`` extra (``open3d-cpu``, ``onnxruntime``, ``jax2onnx``).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from tqdm.auto import tqdm

from tactojax._compilation import CompilationCounter, kernel_count
from tactojax.features import apply_encoder, encode_images
from tactojax.geometry import sensor_pose
from tactojax.io import DEFAULT_ENCODER, open_dataset, read_grasps, resolve_encoder, resolve_shape_model
from tactojax.localize import (BeliefSettings, IcpSettings, LocalizationMap, Localizer, MapLibrary, Touch,
                               empty_belief, identify, localize_baseline, update_belief)
from tactojax.localize._points import POINTS_PER_TOUCH
from tactojax.localize._retrieval import MAX_OPENING_DIFFERENCE_MM
from tactojax.mapping import build_tactile_map, observed_contact
from tactojax.shape import coordinate_bias, predict
from tactojax.simulate import MappingProtocol

try:  # run as ``python benchmarks/whole_touch.py`` or as a module
    from benchmarks._common import format_table, machine_info, write_json
    from benchmarks._peer import PeerPipeline
    from benchmarks.live import simulated
except ImportError:
    from _common import format_table, machine_info, write_json
    from _peer import PeerPipeline
    from live import simulated


def compiled_stage(function, *args):
    """(compiled program, compile seconds, kernels, GFLOP per call) of ``jax.jit(function)(*args)``."""
    start = time.perf_counter()
    compiled = jax.jit(function).lower(*args).compile()
    compile_s = time.perf_counter() - start
    analysis = compiled.cost_analysis()
    analysis = analysis[0] if isinstance(analysis, (list, tuple)) else analysis
    return compiled, compile_s, kernel_count(compiled), float((analysis or {}).get("flops", 0.0)) / 1e9


def median_ms(call, inputs, repeats: int) -> float:
    """Steady-state median of ``call(*inputs[i])`` over ``repeats`` calls cycling through the inputs, ms."""
    jax.block_until_ready(call(*inputs[0]))
    times = []
    for i in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(call(*inputs[i % len(inputs)]))
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def sustained_gflops(size: int = 2048, repeats: int = 10) -> float:
    """What this machine's CPU sustains on a (size x size) float32 matrix product, GFLOP/s."""
    a = jnp.asarray(np.random.default_rng(0).standard_normal((size, size)), jnp.float32)
    product = jax.jit(lambda a: a @ a)
    seconds = median_ms(product, [(a,)], repeats) / 1e3
    return 2 * size ** 3 / seconds / 1e9


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--object", default="scissors")
    parser.add_argument("--work", default="benchmark-data/live", help="simulated data cache (shared with live.py)")
    parser.add_argument("--model", default="bundled:fast-gelslim-0.5")
    parser.add_argument("--encoder", default=DEFAULT_ENCODER, help="feature encoder (default: the CLI's)")
    parser.add_argument("--n", type=int, default=5, help="N of CTI-ICP-N")
    parser.add_argument("--touches", type=int, default=200, help="touches through each pipeline")
    parser.add_argument("--repeats", type=int, default=200, help="calls per stage timing")
    parser.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)),
                        help="ONNX Runtime threads (default: the usable cores)")
    parser.add_argument("--no-peer", action="store_true", help="leave out the peer pipeline")
    parser.add_argument("--json", metavar="PATH")
    args = parser.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    method = f"cti-icp-{args.n}"
    print(f"JAX {jax.__version__} on {jax.devices()[0].device_kind}; {len(os.sched_getaffinity(0))} usable cores")

    grasps = read_grasps(simulated(work, args.object, MappingProtocol(), "map-grid10"))
    tactile_map = build_tactile_map(model, grasps["images"], grasps["T_world_gripper"], grasps["openings"],
                                    args.object, T_world_object=grasps["T_world_object"])
    tactile_map = tactile_map.with_features(encode_images(encoder, tactile_map.stored_images(), progress=True))
    touches = open_dataset(simulated(work, args.object, MappingProtocol(yaws_deg=(10.0,)), "touches-yaw10")).read(
        ["image", "opening_mm", "T_world_gripper", "T_world_object"])
    order = np.random.default_rng(1).permutation(len(touches["image"]))[:args.touches]
    images, openings = touches["image"][order], touches["opening_mm"][order].astype(np.float32)
    T_world_sensor = sensor_pose(jaxlie.SE3(jnp.asarray(touches["T_world_gripper"][order])), jnp.asarray(openings))
    T_object_sensor = jaxlie.SE3(jnp.asarray(touches["T_world_object"][order])).inverse() @ T_world_sensor
    true_positions = np.asarray(T_object_sensor.translation())
    print(f"map: {len(tactile_map)} imprints; {len(images)} new touches")

    # tactojax, stage by stage: what each costs, in time, kernels and operations.
    view, library = LocalizationMap.from_tactile_map(tactile_map), MapLibrary.from_maps([tactile_map])

    bias = coordinate_bias(model)  # once per model, as the Localizer does

    def heightmap_stage(image):
        pixels = image.astype(jnp.float32) / 255.0
        heightmap, mask = predict(model, pixels, bias)
        return heightmap, observed_contact(pixels, model.background, mask, model.mm_per_px)

    def features_stage(image):
        return apply_encoder(encoder, (image.astype(jnp.float32) / 255.0)[None])[0]

    settings = BeliefSettings()

    def belief_stage(heightmap, mask, feature, opening):
        touch = Touch(heightmap=heightmap, mask=mask, feature=feature, opening=opening)
        belief = update_belief(view, empty_belief(view, settings), touch, jaxlie.SE3.identity(), settings)
        return belief.best.wxyz_xyz, belief.probability_within()

    def localize_stage(heightmap, mask, feature, opening):
        chosen, _ = identify(library, feature, opening)
        touch = Touch(heightmap=heightmap, mask=mask, feature=feature, opening=opening)
        return chosen, localize_baseline(jax.random.key(0), view, touch, method=method)

    frames = [(jnp.asarray(image),) for image in images[:20]]
    stages, compiled = {}, {}
    for name, function in tqdm([("heightmap", heightmap_stage), ("features", features_stage)], desc="stages"):
        compiled[name], compile_s, kernels, gflop = compiled_stage(function, *frames[0])
        stages[name] = {"median_ms": median_ms(compiled[name], frames, args.repeats), "kernels": kernels,
                        "compile_s": compile_s, "gflop": gflop}
    queries = [(*compiled["heightmap"](*frame), compiled["features"](*frame), jnp.float32(opening))
               for frame, opening in zip(frames, openings)]
    for name, function in (("belief (one touch)", belief_stage), (f"identify + {method.upper()}", localize_stage)):
        program, compile_s, kernels, gflop = compiled_stage(function, *queries[0])
        stages[name] = {"median_ms": median_ms(program, queries, args.repeats), "kernels": kernels,
                        "compile_s": compile_s, "gflop": gflop}

    # The deployed path: the live Localizer fusing every touch as a grasp of its own (frame and
    # gripper pose in, the belief out), and a frame that updates nothing (a grasp settling).
    localizer = Localizer([tactile_map], model, encoder, settings=settings)
    grippers = touches["T_world_gripper"][order].astype(np.float32)
    estimates, latencies, frame_latencies = [], [], []
    localizer.fuse(images[0], float(openings[0]), jaxlie.SE3(grippers[0]))
    with CompilationCounter() as compiles:
        for image, opening, gripper in tqdm(list(zip(images, openings, grippers)), desc="Localizer", unit="touch"):
            localizer.reset()
            frame_latencies.append(localizer(image, float(opening), jaxlie.SE3(gripper)).latency_s)
            localizer.reset()
            estimate = localizer.fuse(image, float(opening), jaxlie.SE3(gripper))
            estimates.append(estimate)
            latencies.append(estimate.latency_s)
    whole = {"median_ms": 1e3 * float(np.median(latencies)), "kernels": None,
             "frame_without_update_ms": 1e3 * float(np.median(frame_latencies)),
             "compile_s": localizer.compile_s, "recompilations": compiles.count,
             "median_position_error_mm": _median_error(
                 [None if e.T_object_sensor is None else np.asarray(e.T_object_sensor.translation())
                  for e in estimates], true_positions)}

    peak = sustained_gflops()
    network_gflop = stages["heightmap"]["gflop"] + stages["features"]["gflop"]
    floor_ms = 1e3 * network_gflop / peak

    peer = None
    if not args.no_peer:
        settings = IcpSettings()
        pipeline = PeerPipeline(model, encoder, tactile_map, n=args.n, points=POINTS_PER_TOUCH,
                                max_distance_mm=settings.max_distance_mm, iterations=settings.iterations,
                                max_opening_difference_mm=MAX_OPENING_DIFFERENCE_MM, threads=args.threads)
        pipeline(images[0], float(openings[0]))  # ONNX Runtime's first run allocates
        poses, times = [], []
        for image, opening in tqdm(list(zip(images, openings)), desc="peer", unit="touch"):
            pose, spent = pipeline(image, float(opening))
            poses.append(None if pose is None else pose[:3, 3])
            times.append(spent)
        peer = {stage: 1e3 * float(np.median([getattr(t, stage) for t in times]))
                for stage in ("heightmap", "features", "retrieval", "registration")}
        peer["median_ms"] = 1e3 * float(np.median([t.total for t in times]))
        peer["median_position_error_mm"] = _median_error(poses, true_positions)

    rows = [[name, f"{s['median_ms']:.2f}", s["kernels"], f"{s['compile_s']:.1f}", f"{1e3 * s['gflop']:.0f}"]
            for name, s in stages.items()]
    rows.append(["whole touch (Localizer.fuse: the belief)", f"{whole['median_ms']:.2f}", "-",
                 f"{whole['compile_s']:.1f}", "-"])
    rows.append(["a frame that updates nothing (Localizer)", f"{whole['frame_without_update_ms']:.2f}", "-", "-", "-"])
    print(format_table(["tactojax stage", "median ms", "kernels", "compile s", "MFLOP"], rows))
    if peer is not None:
        print(format_table(["peer stage (ONNX Runtime, SciPy, OpenCV, Open3D)", "median ms"],
                           [[k, f"{v:.2f}"] for k, v in peer.items() if k != "median_position_error_mm"]))
    print(format_table(["whole touch", "tactojax (belief)", f"peer ({method.upper()})"], [
        ["median latency (ms)", f"{whole['median_ms']:.2f}", "-" if peer is None else f"{peer['median_ms']:.2f}"],
        ["median position error (mm)", f"{whole['median_position_error_mm']:.2f}",
         "-" if peer is None else f"{peer['median_position_error_mm']:.2f}"],
        ["speed-up over the peer", "-" if peer is None else f"{peer['median_ms'] / whole['median_ms']:.1f}x", ""],
        ["recompilations", whole["recompilations"], ""],
    ]))
    print(f"floor: the networks' {1e3 * network_gflop:.0f} MFLOP at the {peak:.0f} GFLOP/s this CPU sustains on a "
          f"matrix product = {floor_ms:.2f} ms")
    if args.json:
        write_json(args.json, {"object": args.object, "method": method, "encoder": args.encoder,
                               "model": args.model, "touches": len(images), "stages": stages, "whole_touch": whole,
                               "peer": peer, "floor": {"network_gflop": network_gflop, "sustained_gflops": peak,
                                                       "floor_ms": floor_ms},
                               "machine": machine_info()})
        print(f"wrote {args.json}")


def _median_error(positions, true_positions) -> float:
    """Median position error (mm) over the touches with an estimate."""
    errors = [np.linalg.norm(p - t) for p, t in zip(positions, true_positions) if p is not None]
    return float(np.median(errors)) if errors else float("nan")


if __name__ == "__main__":
    main()
