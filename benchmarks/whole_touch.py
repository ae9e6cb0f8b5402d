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
    python benchmarks/whole_touch.py --quick --no-peer     # smoke run: 10 touches, 20 mm grid

Needs the ``benchmark`` extra (``open3d-cpu``, ``onnxruntime``, ``jax2onnx``).
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from tqdm.auto import tqdm

from tactojax import CompilationCounter, kernel_count
from tactojax.features import apply_encoder
from tactojax.geometry import sensor_pose
from tactojax.io import open_dataset, resolve_encoder, resolve_shape_model
from tactojax.localize import (
    COMPILER_OPTIONS,
    BeliefSettings,
    LocalizationMap,
    Localizer,
    Touch,
    empty_belief,
    update_belief,
)
from tactojax.localize.baselines import (MAX_OPENING_DIFFERENCE_MM, POINTS_PER_TOUCH, IcpSettings, MapLibrary, identify,
                                        localize_baseline)
from tactojax.mapping import observed_contact
from tactojax.shape import coordinate_bias, predict
from tactojax.simulate import MappingProtocol

try:  # run as ``python benchmarks/whole_touch.py`` or as a module
    from benchmarks._common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                                    mapping_grid, print_machine, simulated, write_json)
    from benchmarks._peer import PeerPipeline
except ImportError:
    from _common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                         mapping_grid, print_machine, simulated, write_json)
    from _peer import PeerPipeline


def compiled_stage(function, *args, compiler_options=None):
    """(compiled program, compile seconds, kernels, GFLOP per call) of ``jax.jit(function)(*args)``."""
    start = time.perf_counter()
    compiled = jax.jit(function, compiler_options=compiler_options).lower(*args).compile()
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


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_map_arguments(parser)
    parser.add_argument("--n", type=int, default=5, help="N of CTI-ICP-N")
    parser.add_argument("--touches", type=int, default=200, help="touches through each pipeline")
    parser.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)),
                        help="ONNX Runtime threads (default: the usable cores)")
    parser.add_argument("--no-peer", action="store_true", help="leave out the peer pipeline")
    add_common_arguments(parser, quick="10 touches, 10 calls per stage, a 20 mm map", seed=1,
                         seed_help="which new touches are drawn", repeats=200, repeats_help="calls per stage timing")
    args = parser.parse_args()
    if args.quick:
        args.touches, args.repeats = min(args.touches, 10), min(args.repeats, 10)
    return args


def new_touches(args, name: str) -> dict:
    """``--touches`` new touches (yaw 10 deg, off the map's yaws) drawn by ``--seed``: images,
    openings, gripper poses and the true sensor positions (object frame, mm)."""
    grid_mm = mapping_grid(args)
    dataset = simulated(args.work, name, MappingProtocol(grid_mm=grid_mm, yaws_deg=(10.0,)),
                        "touches-yaw10" + ("" if grid_mm == 10 else f"-grid{grid_mm:g}"))
    touches = open_dataset(dataset).read(["image", "opening_mm", "T_world_gripper", "T_world_object"])
    order = np.random.default_rng(args.seed).permutation(len(touches["image"]))[:args.touches]
    openings = touches["opening_mm"][order].astype(np.float32)
    T_world_sensor = sensor_pose(jaxlie.SE3(jnp.asarray(touches["T_world_gripper"][order])), jnp.asarray(openings))
    T_object_sensor = jaxlie.SE3(jnp.asarray(touches["T_world_object"][order])).inverse() @ T_world_sensor
    return {"images": touches["image"][order], "openings": openings,
            "grippers": touches["T_world_gripper"][order].astype(np.float32),
            "true_positions": np.asarray(T_object_sensor.translation())}


def stage_timings(args, tactile_map, model, encoder, settings, images, openings) -> dict:
    """tactojax stage by stage, each jitted on its own: median ms, kernels, compile s, GFLOP. The
    localization stages are compiled as the library compiles its own programs (``COMPILER_OPTIONS``),
    the networks with XLA's defaults, as in the ``Localizer``."""
    view, library = LocalizationMap.from_tactile_map(tactile_map), MapLibrary.from_maps([tactile_map])
    bias = coordinate_bias(model)  # once per model, as the Localizer does
    method = f"cti-icp-{args.n}"

    def heightmap_stage(image):
        pixels = image.astype(jnp.float32) / 255.0
        heightmap, mask = predict(model, pixels, bias)
        return heightmap, observed_contact(pixels, model.background, mask, model.mm_per_px)

    def features_stage(image):
        return apply_encoder(encoder, (image.astype(jnp.float32) / 255.0)[None])[0]

    def belief_stage(heightmap, mask, feature, opening):
        touch = Touch(heightmap=heightmap, mask=mask, feature=feature, opening=opening)
        belief = update_belief(view, empty_belief(view, settings), touch, jaxlie.SE3.identity(), settings)
        return belief.best.wxyz_xyz, belief.probability_within()

    def localize_stage(heightmap, mask, feature, opening):
        chosen, _ = identify(library, feature, opening)
        touch = Touch(heightmap=heightmap, mask=mask, feature=feature, opening=opening)
        return chosen, localize_baseline(jax.random.key(0), view, touch, method=method)

    def measure(function, inputs, compiler_options=None):
        program, compile_s, kernels, gflop = compiled_stage(function, *inputs[0], compiler_options=compiler_options)
        return program, {"median_ms": median_ms(program, inputs, args.repeats), "kernels": kernels,
                         "compile_s": compile_s, "gflop": gflop}

    frames = [(jnp.asarray(image),) for image in images[:20]]
    stages = {}
    heightmap_program, stages["heightmap"] = measure(heightmap_stage, frames)
    features_program, stages["features"] = measure(features_stage, frames)
    queries = [(*heightmap_program(*frame), features_program(*frame), jnp.float32(opening))
               for frame, opening in zip(frames, openings)]
    _, stages["belief (one touch)"] = measure(belief_stage, queries, COMPILER_OPTIONS)
    _, stages[f"identify + {method.upper()}"] = measure(localize_stage, queries, COMPILER_OPTIONS)
    return stages


def deployed(tactile_map, model, encoder, settings, touches) -> dict:
    """The live Localizer fusing every touch as a grasp of its own (frame and gripper pose in,
    the belief out), and a frame that updates nothing (a grasp settling)."""
    localizer = Localizer([tactile_map], model, encoder, settings=settings)
    images, openings, grippers = touches["images"], touches["openings"], touches["grippers"]
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
    return {"median_ms": 1e3 * float(np.median(latencies)), "kernels": None,
            "frame_without_update_ms": 1e3 * float(np.median(frame_latencies)),
            "compile_s": localizer.compile_s, "recompilations": compiles.count,
            "median_position_error_mm": _median_error(
                [None if e.T_object_sensor is None else np.asarray(e.T_object_sensor.translation())
                 for e in estimates], touches["true_positions"])}


def peer_pipeline(args, tactile_map, model, encoder, touches) -> dict:
    """The peer (``benchmarks/_peer.py``) on the same touches: median ms per stage and in all
    (None when its libraries are not installed)."""
    settings = IcpSettings()
    try:
        pipeline = PeerPipeline(model, encoder, tactile_map, n=args.n, points=POINTS_PER_TOUCH,
                                max_distance_mm=settings.max_distance_mm, iterations=settings.iterations,
                                max_opening_difference_mm=MAX_OPENING_DIFFERENCE_MM, threads=args.threads)
    except ImportError as error:  # the benchmark extra (open3d-cpu, onnxruntime, jax2onnx) is not installed
        print(f"peer pipeline left out: {error}")
        return None
    images, openings = touches["images"], touches["openings"]
    pipeline(images[0], float(openings[0]))  # ONNX Runtime's first run allocates
    poses, times = [], []
    for image, opening in tqdm(list(zip(images, openings)), desc="peer", unit="touch"):
        pose, spent = pipeline(image, float(opening))
        poses.append(None if pose is None else pose[:3, 3])
        times.append(spent)
    peer = {stage: 1e3 * float(np.median([getattr(t, stage) for t in times]))
            for stage in ("heightmap", "features", "retrieval", "registration")}
    peer["median_ms"] = 1e3 * float(np.median([t.total for t in times]))
    peer["median_position_error_mm"] = _median_error(poses, touches["true_positions"])
    return peer


def print_results(result: dict) -> None:
    stages, whole, peer, floor = result["stages"], result["whole_touch"], result["peer"], result["floor"]
    rows = [[name, f"{s['median_ms']:.2f}", s["kernels"], f"{s['compile_s']:.1f}", f"{1e3 * s['gflop']:.0f}"]
            for name, s in stages.items()]
    rows.append(["whole touch (Localizer.fuse: the belief)", f"{whole['median_ms']:.2f}", "-",
                 f"{whole['compile_s']:.1f}", "-"])
    rows.append(["a frame that updates nothing (Localizer)", f"{whole['frame_without_update_ms']:.2f}", "-", "-", "-"])
    print(format_table(["tactojax stage", "median ms", "kernels", "compile s", "MFLOP"], rows))
    if peer is not None:
        print(format_table(["peer stage (ONNX Runtime, SciPy, OpenCV, Open3D)", "median ms"],
                           [[k, f"{v:.2f}"] for k, v in peer.items() if k != "median_position_error_mm"]))
    print(format_table(["whole touch", "tactojax (belief)", f"peer ({result['method'].upper()})"], [
        ["median latency (ms)", f"{whole['median_ms']:.2f}", "-" if peer is None else f"{peer['median_ms']:.2f}"],
        ["median position error (mm)", f"{whole['median_position_error_mm']:.2f}",
         "-" if peer is None else f"{peer['median_position_error_mm']:.2f}"],
        ["speed-up over the peer", "-" if peer is None else f"{peer['median_ms'] / whole['median_ms']:.1f}x", ""],
        ["recompilations", whole["recompilations"], ""],
    ]))
    print(f"floor: the networks' {1e3 * floor['network_gflop']:.0f} MFLOP at the {floor['sustained_gflops']:.0f} "
          f"GFLOP/s this CPU sustains on a matrix product = {floor['floor_ms']:.2f} ms")


def main() -> None:
    args = parse_args()
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    print_machine()
    ((tactile_map, _),) = load_maps(args, model, encoder)
    touches = new_touches(args, tactile_map.object_id)
    print(f"map: {len(tactile_map)} imprints; {len(touches['images'])} new touches")
    settings = BeliefSettings()
    stages = stage_timings(args, tactile_map, model, encoder, settings, touches["images"], touches["openings"])
    whole = deployed(tactile_map, model, encoder, settings, touches)
    network_gflop, peak = stages["heightmap"]["gflop"] + stages["features"]["gflop"], sustained_gflops()
    peer = None if args.no_peer else peer_pipeline(args, tactile_map, model, encoder, touches)
    result = {"object": tactile_map.object_id, "method": f"cti-icp-{args.n}", "encoder": args.encoder,
              "model": args.model, "touches": len(touches["images"]), "seed": args.seed, "stages": stages,
              "whole_touch": whole, "peer": peer,
              "floor": {"network_gflop": network_gflop, "sustained_gflops": peak,
                        "floor_ms": 1e3 * network_gflop / peak},
              "machine": machine_info()}
    print_results(result)
    if args.json:
        write_json(args.json, result)
        print(f"wrote {args.json}")


def _median_error(positions, true_positions) -> float:
    """Median position error (mm) over the touches with an estimate."""
    errors = [np.linalg.norm(p - t) for p, t in zip(positions, true_positions) if p is not None]
    return float(np.median(errors)) if errors else float("nan")


if __name__ == "__main__":
    main()
