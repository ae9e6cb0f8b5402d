"""The live localization loop from a recorded video of simulated frames (issue 6).

Builds (once, cached) the tactile map of an object on the paper's protocol, simulates a second
set of grasps that are not in the map (another yaw), writes their frames to a lossless video
file, then runs ``tactojax.hardware.live_estimates`` on that video through ``OpenCVCamera``
exactly as ``tactojax localize-live`` does: every frame in order, one precompiled program per
frame (heightmap, features, identification, CTI-ICP-N). Reports the sustained rate, latency
percentiles, compile time at start-up, recompilations (counted, must be 0) and the median
position error of the estimates against the simulator's truth; the reference in the same run is
the same touches through the stage-by-stage API (``predict``, ``encode_image``, ``localize``).

    python benchmarks/live.py --json live.json
"""

from __future__ import annotations

import argparse
import time
import zlib
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax._compilation import CompilationCounter
from tactojax.features import encode_image, encode_images
from tactojax.geometry import sensor_pose
from tactojax.hardware import LiveStatistics, OpenCVCamera, live_estimates, write_video
from tactojax.io import (DEFAULT_ENCODER, open_dataset, read_grasps,
                         resolve_encoder, resolve_shape_model, simulate_to_dataset)
from tactojax.localize import LocalizationMap, Localizer, Query, localize
from tactojax.mapping import build_tactile_map, observed_contact
from tactojax.objects import get_object
from tactojax.sensor import gelslim
from tactojax.shape import predict
from tactojax.simulate import MappingProtocol

try:  # run as ``python benchmarks/live.py`` or as a module
    from benchmarks._common import format_table, machine_info, write_json
except ImportError:
    from _common import format_table, machine_info, write_json


def simulated(work: Path, name: str, protocol: MappingProtocol, tag: str) -> Path:
    path = work / f"{name}-{tag}"
    if not (path / "manifest.json").exists():
        simulate_to_dataset(path, jax.random.key(zlib.crc32(tag.encode())), gelslim(scale=0.5), get_object(name), protocol)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--object", default="scissors")
    parser.add_argument("--work", default="benchmark-data/live", help="simulated data cache")
    parser.add_argument("--model", default="bundled:fast-gelslim-0.5")
    parser.add_argument("--encoder", default=DEFAULT_ENCODER, help="feature encoder (default: the CLI's)")
    parser.add_argument("--method", default="cti-icp-5")
    parser.add_argument("--frames", type=int, default=300, help="frames in the video (default 300)")
    parser.add_argument("--fps", type=float, default=30.0, help="the video's nominal frame rate")
    parser.add_argument("--json", metavar="PATH")
    args = parser.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)

    grasps = read_grasps(simulated(work, args.object, MappingProtocol(), "map-grid10"))
    tactile_map = build_tactile_map(model, grasps["images"], grasps["T_world_gripper"], grasps["openings"],
                                    args.object, T_world_object=grasps["T_world_object"])
    tactile_map = tactile_map.with_features(encode_images(encoder, tactile_map.images, progress=True))

    # New touches, not in the map: yaw 10 deg (the map has 0 and +-20).
    touches_path = simulated(work, args.object, MappingProtocol(yaws_deg=(10.0,)), "touches-yaw10")
    touches = open_dataset(touches_path).read(["image", "opening_mm", "T_world_gripper", "T_world_object"])
    order = np.random.default_rng(0).permutation(len(touches["image"]))[:args.frames]
    images, openings = touches["image"][order], touches["opening_mm"][order]
    video = write_video(work / f"{args.object}-touches.mkv", images, fps=args.fps)
    T_world_sensor = sensor_pose(jaxlie.SE3(jnp.asarray(touches["T_world_gripper"][order])), jnp.asarray(openings))
    T_object_sensor = jaxlie.SE3(jnp.asarray(touches["T_world_object"][order])).inverse() @ T_world_sensor
    true_positions = np.asarray(T_object_sensor.translation())

    print("compiling the live program ...", flush=True)
    localizer = Localizer([tactile_map], model, encoder, method=args.method)
    statistics, estimates = LiveStatistics(), []
    next_opening = iter(openings.tolist()).__next__  # frames come in order: one opening each
    with OpenCVCamera(video, gelslim(scale=0.5)) as camera, CompilationCounter() as compiles:
        for frame, estimate in live_estimates(camera, localizer, next_opening):
            statistics.add(frame, estimate)
            estimates.append(estimate)
    statistics.recompilations = compiles.count
    for message in compiles.messages:
        print("recompiled:", message[:300])
    live = statistics.summary()
    touched = [i for i, e in enumerate(estimates) if e.contact]  # a frame without a touch has no estimate
    live_positions = np.stack([np.asarray(estimates[i].T_object_sensor.translation()) for i in touched])
    live_error = float(np.median(np.linalg.norm(live_positions - true_positions[touched], axis=1)))

    # Reference: the same touches through the stage-by-stage API (each stage its own jit).
    view = LocalizationMap.from_tactile_map(tactile_map)
    reference_times, reference_positions = [], []
    for index, (image, opening) in enumerate(zip(images, openings)):
        start = time.perf_counter()
        pixels = jnp.asarray(image, jnp.float32) / 255.0
        heightmap, mask = predict(model, pixels)
        mask = observed_contact(pixels, model.background, mask, model.mm_per_px)
        if index not in touched:
            continue
        query = Query(heightmap=heightmap, mask=mask, feature=encode_image(encoder, image), opening=jnp.float32(opening))
        estimate = jax.block_until_ready(localize(jax.random.key(0), view, query, method=args.method))
        if reference_positions:  # the first call compiles
            reference_times.append(time.perf_counter() - start)
        reference_positions.append(np.asarray(estimate.T_object_sensor.translation()))
    reference_error = float(np.median(np.linalg.norm(np.stack(reference_positions) - true_positions[touched],
                                                     axis=1)))
    reference_ms = 1e3 * float(np.median(reference_times))

    print(format_table(["pipeline", "frames", "rate (Hz)", "latency median / p95 (ms)", "position error median (mm)",
                        "recompilations"], [
        [f"live (one AOT program; {len(touched)} with contact)", live["frames"], f"{live['rate_hz']:.1f}",
         f"{live['latency_ms']['median']:.1f} / {live['latency_ms']['p95']:.1f}", f"{live_error:.2f}",
         live["recompilations"]],
        ["stage by stage (reference)", len(images), f"{1e3 / reference_ms:.1f}", f"{reference_ms:.1f} / -",
         f"{reference_error:.2f}", "-"],
    ]))
    print(f"start-up compile: {localizer.compile_s:.1f} s; kernels per touch: {localizer.kernels}; "
          f"dropped frames: {live['dropped_frames']}")
    if args.json:
        write_json(args.json, {
            "object": args.object, "method": localizer.method.name, "map_imprints": len(tactile_map),
            "video": str(video), "compile_s": localizer.compile_s, "live": live, "frames_with_contact": len(touched),
            "kernels": localizer.kernels,
            "live_median_position_error_mm": live_error, "reference_ms_per_touch": reference_ms,
            "reference_median_position_error_mm": reference_error, "machine": machine_info()})
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
