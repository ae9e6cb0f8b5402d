"""The live loop on camera frames with their gripper poses: grasps fused into the pose belief (issue 27).

A new-grasps test set of the object (episodes of G grasps, the object staying put within an
episode; simulated once and cached, or ``--test DIR``) is played as the sensor's camera sees it:
every grasp as ``settle + hold`` frames of the finger at rest, then ``gap`` frames without
contact (the gripper opens and moves on). The frames are written to a lossless video and read
back through ``OpenCVCamera``; each goes with the gripper's pose and opening at that frame
(``live_estimates(..., gripper_pose=...)``), exactly as ``tactojax localize-live`` runs. The
``Localizer`` updates its belief once per settled grasp and fuses the grasps of an episode by
their poses (the kinematics); it is reset between episodes (the object is put down elsewhere).

Reported: the sustained rate and the latency percentiles of every frame (and of the frames that
updated the belief), the compile time at start-up, the recompilations (counted from the first
frame: must be 0), and after each grasp g = 1..G the error of that frame's sensor pose against
the simulator's truth (the paper's RMSE of the touch's true contact cloud, up to the object's
symmetry; median and share within 2 mm) beside the belief's mean P(within 2 mm). The reference in
the same run: the same grasps through the stage-by-stage API (``predict``, ``encode_image``,
``localize`` continuing the episode's belief), its time per grasp and its errors (the same
belief: the same numbers up to floating point).

    python benchmarks/live.py --json live.json
    python benchmarks/live.py --map scissors-cal.npz --test data/fresh-scissors --episodes 8
    python benchmarks/live.py --map scissors-cal.npz --test data/fresh-scissors --episodes 32 --fingers 2

With ``--fingers 2`` the opposite finger's frames are a second video read in step
(``live_estimates(..., second_camera=...)``, ``tactojax localize-live --second-camera``), and
every settled grasp updates the belief with both fingers, as ``eval-localization --test
--fingers 2`` fuses them.
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
from scipy.spatial.transform import Rotation

from tactojax._compilation import CompilationCounter
from tactojax.features import encode_image, encode_images
from tactojax.geometry import opposite_sensor_pose, pixel_grid, sensor_pose
from tactojax.hardware import LiveStatistics, OpenCVCamera, live_estimates, write_video
from tactojax.io import (DEFAULT_ENCODER, load_tactile_map, read_grasps, read_test_grasps, resolve_encoder,
                         resolve_shape_model, tactile_map_metadata)
from tactojax.localize import (BeliefSettings, LocalizationMap, Localizer, Touch, calibration_from_json,
                               localize)
from tactojax.mapping import build_tactile_map, observed_contact
from tactojax.objects import get_object
from tactojax.sensor import gelslim
from tactojax.shape import predict
from tactojax.simulate import GraspsProtocol, MappingProtocol, simulate_to_dataset

try:  # run as ``python benchmarks/live.py`` or as a module
    from benchmarks._common import format_table, machine_info, write_json
except ImportError:
    from _common import format_table, machine_info, write_json

RELEASED_MM = 10.0
"""How much wider the gripper stands on the frames between grasps, mm."""


def simulated(work: Path, name: str, protocol, tag: str) -> Path:
    """A simulated dataset of ``name`` (written once under ``work``, then read from there)."""
    path = work / f"{name}-{tag}"
    if not (path / "manifest.json").exists():
        simulate_to_dataset(path, jax.random.key(zlib.crc32(tag.encode())), gelslim(scale=0.5), get_object(name),
                            protocol)
    return path


def load_map(args, work: Path, model, encoder):
    """The object's map with features, and its stored belief calibration (None: uncalibrated)."""
    if args.map is None:
        grasps = read_grasps(simulated(work, args.object, MappingProtocol(), "map-grid10"))
        tactile_map = build_tactile_map(model, grasps["images"], grasps["T_world_gripper"], grasps["openings"],
                                        args.object, T_world_object=grasps["T_world_object"])
        return tactile_map.with_features(encode_images(encoder, tactile_map.stored_images(), progress=True)), None
    tactile_map = load_tactile_map(args.map, images=True)
    if tactile_map.features.shape[1] == 0:
        tactile_map = tactile_map.with_features(encode_images(encoder, tactile_map.stored_images(), progress=True))
    stored = tactile_map_metadata(args.map).get("metadata", {}).get("belief_calibration")
    usable = stored is not None and stored.get("encoder", args.encoder) == args.encoder
    return tactile_map, (calibration_from_json(stored) if usable else None)


def true_clouds(heightmaps: np.ndarray, masks: np.ndarray, mm_per_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) means and (N, 3, 3) covariances of the touches' true contact clouds, sensor frame, mm."""
    xy = np.asarray(pixel_grid(*heightmaps.shape[1:], mm_per_px), np.float64)
    means, covariances = [], []
    for heightmap, mask in zip(heightmaps, masks):
        cloud = np.concatenate([xy[mask], -heightmap[mask][:, None].astype(np.float64)], axis=1)
        if len(cloud) == 0:
            cloud = np.zeros((1, 3))
        means.append(cloud.mean(axis=0))
        covariances.append(np.cov(cloud.T, bias=True).reshape(3, 3))
    return np.stack(means), np.stack(covariances)


def matrix(wxyz_xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation matrix and translation of a (7,) wxyz_xyz pose."""
    wxyz_xyz = np.asarray(wxyz_xyz, np.float64)
    return Rotation.from_quat(wxyz_xyz[[1, 2, 3, 0]]).as_matrix(), wxyz_xyz[4:]


def cloud_error(mean, covariance, T_true, T_estimate, symmetries) -> float:
    """The paper's error: RMSE (mm) between a touch's cloud (its moments) at its true and its
    estimated sensor pose, the estimate taken through the closest of the object's symmetries
    ((S, 3, 3) rotations, (S, 3) translations; NumPy, so that the loop compiles nothing)."""
    (R_true, t_true), (R_estimate, t_estimate) = matrix(T_true), matrix(T_estimate)
    rotations, translations = symmetries
    R_copies = rotations @ R_estimate
    t_copies = rotations @ t_estimate + translations
    A = R_true[None] - R_copies
    offset = A @ mean + t_true - t_copies
    spread = np.einsum("sij,jk,sik->s", A, covariance, A)
    return float(np.sqrt(np.maximum(spread, 0.0) + np.sum(offset**2, axis=-1)).min())


def per_grasp(errors: np.ndarray, probabilities: np.ndarray) -> list[dict]:
    """Per grasp index (columns of (E, G) arrays, NaN where a grasp gave no estimate): count, median
    error, share within 2 mm, mean P(within 2 mm)."""
    rows = []
    for g in range(errors.shape[1]):
        found = np.isfinite(errors[:, g])
        rows.append({"grasp": g + 1, "estimates": int(found.sum()),
                     "median_rmse_mm": float(np.median(errors[found, g])) if found.any() else None,
                     "within_2mm": float(np.mean(errors[found, g] <= 2.0)) if found.any() else None,
                     "mean_p_within_2mm": float(np.mean(probabilities[found, g])) if found.any() else None})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--object", default="scissors")
    parser.add_argument("--work", default="benchmark-data/live", help="simulated data cache")
    parser.add_argument("--map", help="a saved map (.npz; its stored belief calibration is used if it was fit "
                                      "with --encoder); default: simulate and map --object")
    parser.add_argument("--test", metavar="DIR", help="a new-grasps test set of the object (default: simulate one)")
    parser.add_argument("--model", default="bundled:fast-gelslim-0.5")
    parser.add_argument("--encoder", default=DEFAULT_ENCODER, help="feature encoder (default: the CLI's)")
    parser.add_argument("--episodes", type=int, default=8, help="episodes played (default 8)")
    parser.add_argument("--fingers", type=int, choices=[1, 2], default=1,
                        help="fingers with a sensor (2: the opposite finger's frames come from a second camera, "
                             "and every grasp's update fuses both; the test set must record both)")
    parser.add_argument("--grasps", type=int, default=3, help="grasps per simulated episode (default 3)")
    parser.add_argument("--hold", type=int, default=2, help="frames at rest after a grasp settled (default 2)")
    parser.add_argument("--gap", type=int, default=2, help="frames without contact between grasps (default 2)")
    parser.add_argument("--fps", type=float, default=30.0, help="the video's nominal frame rate")
    parser.add_argument("--no-reference", action="store_true", help="leave out the stage-by-stage reference")
    parser.add_argument("--json", metavar="PATH")
    args = parser.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    tactile_map, calibration = load_map(args, work, model, encoder)
    name = tactile_map.object_id

    test = Path(args.test) if args.test else simulated(
        work, name, GraspsProtocol(episodes=args.episodes, grasps_per_episode=args.grasps, fingers=args.fingers),
        f"grasps-e{args.episodes}-g{args.grasps}-f{args.fingers}")
    fields = ["image", "heightmap", "mask", "opening_mm", "T_world_gripper", "T_world_sensor", "T_world_object"]
    records = read_test_grasps(test, fields, object_id=name)
    grasps = int(np.sum((records["episode"] == records["episode"][0]) & (records["finger"] == 0)))
    opposite = {key: value[records["finger"] == 1] for key, value in records.items()}
    records = {key: value[records["finger"] == 0] for key, value in records.items()}
    if args.fingers == 2 and len(opposite["image"]) != len(records["image"]):
        raise SystemExit(f"--fingers 2: {test} does not record both fingers of every grasp "
                         "(simulate it with --fingers 2)")
    episodes = min(args.episodes, len(records["image"]) // grasps)
    records = {key: value[:episodes * grasps] for key, value in records.items()}
    opposite = {key: value[:episodes * grasps] for key, value in opposite.items()}
    T_world_object = jaxlie.SE3(jnp.asarray(records["T_world_object"]))
    truth = np.asarray((T_world_object.inverse() @ jaxlie.SE3(jnp.asarray(records["T_world_sensor"]))).wxyz_xyz)
    means, covariances = true_clouds(records["heightmap"], records["mask"], tactile_map.mm_per_px)
    group = get_object(name).symmetry.transforms()
    symmetries = (np.asarray(group.rotation().as_matrix(), np.float64), np.asarray(group.translation(), np.float64))

    print(f"compiling the live programs ({name}: {len(tactile_map)} imprints) ...", flush=True)
    settings = BeliefSettings()
    localizer = Localizer([tactile_map], model, encoder, calibrations=[calibration], settings=settings)
    settle = localizer.live.settle_frames

    # The frames: each grasp at rest (settle + hold), then released (gap), with the gripper's pose.
    background = np.round(np.asarray(model.background) * 255).astype(np.uint8)
    frames, opposite_frames, openings, poses, touch_of_frame = [], [], [], [], []
    for t in range(len(records["image"])):
        for k in range(settle + args.hold + args.gap):
            released = k >= settle + args.hold
            frames.append(background if released else records["image"][t])
            if args.fingers == 2:
                opposite_frames.append(background if released else opposite["image"][t])
            openings.append(float(records["opening_mm"][t]) + (RELEASED_MM if released else 0.0))
            poses.append(records["T_world_gripper"][t].astype(np.float32))
            touch_of_frame.append(t)
    video = write_video(work / f"{name}-grasps-e{episodes}-g{grasps}.mkv", np.stack(frames), fps=args.fps)
    opposite_video = None if args.fingers == 1 else write_video(
        work / f"{name}-grasps-e{episodes}-g{grasps}-opposite.mkv", np.stack(opposite_frames), fps=args.fps)
    frames_per_episode = grasps * (settle + args.hold + args.gap)

    statistics, updated_ms = LiveStatistics(), []
    live_errors, live_probability = np.full((episodes, grasps), np.nan), np.full((episodes, grasps), np.nan)
    next_opening = iter(openings).__next__  # frames come in order: one opening each
    second_camera = None if opposite_video is None else OpenCVCamera(opposite_video, gelslim(scale=0.5))
    with OpenCVCamera(video, gelslim(scale=0.5)) as camera, CompilationCounter() as compiles:
        for frame, estimate in live_estimates(camera, localizer, next_opening, second_camera=second_camera,
                                              gripper_pose=lambda frame: jaxlie.SE3(poses[frame.index])):
            statistics.add(frame, estimate)
            t = touch_of_frame[frame.index]
            if estimate.updated:
                updated_ms.append(1e3 * estimate.latency_s)
                T_estimate = np.asarray(estimate.T_object_sensor.wxyz_xyz)
                live_errors[t // grasps, t % grasps] = cloud_error(means[t], covariances[t], truth[t], T_estimate,
                                                                   symmetries)
                live_probability[t // grasps, t % grasps] = estimate.probability_within
            if (frame.index + 1) % frames_per_episode == 0:
                localizer.reset()  # the object is put down elsewhere
    if second_camera is not None:
        second_camera.close()
    statistics.recompilations = compiles.count
    for message in compiles.messages:
        print("recompiled:", message[:300])
    live = statistics.summary()

    reference = None
    if not args.no_reference:  # the same grasps, stage by stage through the public API
        view = LocalizationMap.from_tactile_map(tactile_map, calibration=calibration)

        @jax.jit
        def observe(image):
            pixels = image.astype(jnp.float32) / 255.0
            heightmap, mask = predict(model, pixels)
            return heightmap, observed_contact(pixels, model.background, mask, model.mm_per_px)

        def observe_touch(image, opening):
            heightmap, mask = observe(image)
            return Touch(heightmap=heightmap, mask=mask, feature=encode_image(encoder, image), opening=opening)

        errors, probability = np.full((episodes, grasps), np.nan), np.full((episodes, grasps), np.nan)
        seconds, skipped = [], 0
        for e in range(episodes):
            belief = None
            for g in range(grasps):
                t = e * grasps + g
                start = time.perf_counter()
                opening = jnp.float32(records["opening_mm"][t])
                T_world_gripper = jaxlie.SE3(jnp.asarray(records["T_world_gripper"][t], jnp.float32))
                T_world_sensor = sensor_pose(T_world_gripper, opening)
                touches, T_world_touches = [observe_touch(records["image"][t], opening)], [T_world_sensor]
                if args.fingers == 2:
                    touches.append(observe_touch(opposite["image"][t], opening))
                    T_world_touches.append(opposite_sensor_pose(T_world_gripper, opening))
                try:
                    belief = jax.block_until_ready(localize(view, touches, T_world_touches, belief=belief,
                                                            settings=settings))
                except ValueError:  # no contact in the episode's first grasp: nothing to localize yet
                    skipped += 1
                    continue
                seconds.append(time.perf_counter() - start)
                errors[e, g] = cloud_error(means[t], covariances[t], truth[t],
                                           np.asarray(belief.sensor_pose(T_world_sensor).wxyz_xyz), symmetries)
                probability[e, g] = float(belief.probability_within())
        reference = {"ms_per_grasp": {"median": 1e3 * float(np.median(seconds[1:])),
                                      "p95": 1e3 * float(np.percentile(seconds[1:], 95))},
                     "first_call_s": seconds[0], "skipped": skipped, "per_grasp": per_grasp(errors, probability)}

    live_rows = per_grasp(live_errors, live_probability)
    print(format_table(
        ["loop", "frames", "rate (Hz)", "latency median / p95 / max (ms)", "belief updates: median / max (ms)",
         "recompilations"],
        [[f"live: {episodes} episodes x {grasps} grasps x {args.fingers} finger{'s' * (args.fingers > 1)}, each {settle}+{args.hold} frames at rest + {args.gap} "
          "released", live["frames"], f"{live['rate_hz']:.1f}",
          f"{live['latency_ms']['median']:.1f} / {live['latency_ms']['p95']:.1f} / {live['latency_ms']['max']:.1f}",
          f"{np.median(updated_ms):.1f} / {np.max(updated_ms):.1f}" if updated_ms else "-", live["recompilations"]]]))
    headers = ["after grasp", "live: estimates", "median RMSE (mm)", "<= 2 mm", "mean P(<= 2 mm)"]
    rows = [[r["grasp"], r["estimates"], r["median_rmse_mm"], r["within_2mm"], r["mean_p_within_2mm"]]
            for r in live_rows]
    if reference is not None:
        headers += ["reference: median RMSE (mm)", "<= 2 mm"]
        rows = [row + [r["median_rmse_mm"], r["within_2mm"]] for row, r in zip(rows, reference["per_grasp"])]
    print(format_table(headers, rows))
    print(f"start-up compile: {localizer.compile_s:.1f} s; errors up to the {name}'s {len(symmetries[1])} "
          f"symmetries; belief calibration: {'stored' if calibration is not None else 'none (default)'}")
    if reference is not None:
        print(f"reference (stage by stage, localize() per grasp): {reference['ms_per_grasp']['median']:.1f} ms "
              f"median per grasp (first call, compiling: {reference['first_call_s']:.1f} s)")
    if args.json:
        write_json(args.json, {
            "object": name, "map_imprints": len(tactile_map), "test": str(test), "episodes": episodes,
            "grasps_per_episode": grasps, "fingers": args.fingers, "settle_frames": settle, "hold_frames": args.hold, "gap_frames": args.gap,
            "video": str(video), "calibrated": calibration is not None, "compile_s": localizer.compile_s,
            "live": live, "belief_update_ms": {"median": float(np.median(updated_ms)) if updated_ms else None,
                                               "max": float(np.max(updated_ms)) if updated_ms else None},
            "per_grasp": live_rows, "reference": reference, "machine": machine_info()})
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
