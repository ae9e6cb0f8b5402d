"""The live loop on camera frames with their gripper poses: grasps fused into the pose belief (issue 27).

A new-grasps test set of the object (episodes of G grasps, the object staying put within an
episode; simulated once and cached, or ``--test DIR``) is played as the sensor's camera sees it:
every grasp as ``settle + hold`` frames of the finger at rest, then ``gap`` frames without
contact (the gripper opens and moves on). The frames are written to a lossless video and read
back through ``OpenCVCamera`` (decoded ahead in a background thread, ``--read-ahead``); each
goes with the gripper's pose and opening at that frame (``live_estimates(...,
gripper_pose=...)``), as ``tactojax localize-live`` runs. The
``Localizer`` updates its belief once per settled grasp and fuses the grasps of an episode by
their poses (the kinematics); it is reset between episodes (the object is put down elsewhere).

Reported: the sustained rate and the latency percentiles of every frame (and of the frames that
updated the belief), the compile time at start-up, the recompilations (counted from the first
frame: must be 0), and after each grasp g = 1..G the error of that frame's sensor pose against
the simulator's truth (the paper's RMSE of the touch's true contact cloud, up to the object's
symmetry; median and share within 2 mm) beside the belief's mean P(within 2 mm). The reference in
the same run: the same grasps through the stage-by-stage API (``touch_from_image`` for every
finger, ``localize`` continuing the episode's belief), its time per grasp and its errors (the same
belief: the same numbers up to floating point).

    python benchmarks/live.py --json live.json
    python benchmarks/live.py scissors-cal.npz --test data/fresh-scissors --episodes 8
    python benchmarks/live.py scissors-cal.npz --test data/fresh-scissors --episodes 32 --fingers 2
    python benchmarks/live.py --quick         # smoke run: 2 episodes of 2 grasps on a 20 mm map

With ``--fingers 2`` the opposite finger's frames are a second video read in step
(``live_estimates(..., second_camera=...)``, ``tactojax localize-live --second-camera``), and
every settled grasp updates the belief with both fingers, as ``eval-localization --test
--fingers 2`` fuses them.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from scipy.spatial.transform import Rotation

from tactojax import CompilationCounter
from tactojax.geometry import opposite_sensor_pose, pixel_grid, sensor_pose
from tactojax.hardware import LiveStatistics, OpenCVCamera, live_estimates, write_video
from tactojax.io import read_test_grasps, resolve_encoder, resolve_shape_model
from tactojax.localize import BeliefSettings, LiveSettings, LocalizationMap, Localizer, localize, touch_from_image
from tactojax.objects import get_object
from tactojax.sensor import gelslim

try:  # run as ``python benchmarks/live.py`` or as a module
    from benchmarks._common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                                    new_grasps_set, write_json)
except ImportError:
    from _common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                         new_grasps_set, write_json)

RELEASED_MM = 10.0
"""How much wider the gripper stands on the frames between grasps, mm."""


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


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_map_arguments(parser)
    parser.add_argument("--test", metavar="DIR", help="a new-grasps test set of the object (default: simulate one)")
    parser.add_argument("--episodes", type=int, default=8, help="episodes played (default 8)")
    parser.add_argument("--fingers", type=int, choices=[1, 2], default=1,
                        help="fingers with a sensor (2: the opposite finger's frames come from a second camera, "
                             "and every grasp's update fuses both; the test set must record both)")
    parser.add_argument("--grasps", type=int, default=3, help="grasps per simulated episode (default 3)")
    parser.add_argument("--hold", type=int, default=2, help="frames at rest after a grasp settled (default 2)")
    parser.add_argument("--gap", type=int, default=2, help="frames without contact between grasps (default 2)")
    parser.add_argument("--fps", type=float, default=30.0, help="the video's nominal frame rate")
    parser.add_argument("--realtime", action="store_true",
                        help="deliver the frames at --fps, as a live camera does, and report how many came out "
                             "more than a frame period late (default: as fast as the loop takes them)")
    parser.add_argument("--read-ahead", type=int, default=4, metavar="N",
                        help="frames each video is decoded ahead in a background thread (live_estimates' "
                             "read_ahead; 0: decoded in the loop, as before 2026-11-28; default 4)")
    parser.add_argument("--no-reference", action="store_true", help="leave out the stage-by-stage reference")
    parser.add_argument("--synchronous-update", action="store_true",
                        help="update the belief inside the frame call that settles a grasp (default: in the "
                             "background, LiveSettings.background_update, as tactojax localize-live does)")
    add_common_arguments(parser, quick="2 episodes of 2 grasps, a 20 mm map", seed_help="simulated test set")
    args = parser.parse_args()
    if args.quick:
        args.episodes, args.grasps = min(args.episodes, 2), min(args.grasps, 2)
    return args


def read_episodes(args, test: Path, name: str) -> tuple[dict, dict, int, int]:
    """The test set's grasps of finger 0 and of the opposite finger, whole episodes only:
    (records, opposite records, episodes, grasps per episode)."""
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
    return records, opposite, episodes, grasps


def ground_truth(records: dict, name: str, mm_per_px: float):
    """The touches' true sensor poses in the object frame (wxyz_xyz), their true clouds' means
    and covariances, and the object's symmetries (rotations, translations), for :func:`cloud_error`."""
    T_world_object = jaxlie.SE3(jnp.asarray(records["T_world_object"]))
    truth = np.asarray((T_world_object.inverse() @ jaxlie.SE3(jnp.asarray(records["T_world_sensor"]))).wxyz_xyz)
    means, covariances = true_clouds(records["heightmap"], records["mask"], mm_per_px)
    group = get_object(name).symmetry.transforms()
    symmetries = (np.asarray(group.rotation().as_matrix(), np.float64), np.asarray(group.translation(), np.float64))
    return truth, means, covariances, symmetries


def write_videos(args, work: Path, name: str, records: dict, opposite: dict, background: np.ndarray, settle: int,
                 label: str):
    """The frames as lossless videos: each grasp at rest (settle + hold), then released (gap).
    Returns (video, opposite video or None, per frame: opening and gripper pose)."""
    frames, opposite_frames, openings, poses = [], [], [], []
    for t in range(len(records["image"])):
        for k in range(settle + args.hold + args.gap):
            released = k >= settle + args.hold
            frames.append(background if released else records["image"][t])
            if args.fingers == 2:
                opposite_frames.append(background if released else opposite["image"][t])
            openings.append(float(records["opening_mm"][t]) + (RELEASED_MM if released else 0.0))
            poses.append(records["T_world_gripper"][t].astype(np.float32))
    work.mkdir(parents=True, exist_ok=True)
    video = write_video(work / f"{name}-{label}.mkv", np.stack(frames), fps=args.fps)
    opposite_video = None if args.fingers == 1 else write_video(
        work / f"{name}-{label}-opposite.mkv", np.stack(opposite_frames), fps=args.fps)
    return video, opposite_video, openings, poses


class PacedCamera:
    """A camera that delivers a video's frames at ``fps``, as a live camera does (``--realtime``):
    each frame is due ``index / fps`` after the first; :meth:`delay_s` is how long after its due
    time a frame's estimate came out (more than one frame period: the loop fell behind)."""

    def __init__(self, camera, fps: float):
        self.camera, self.period_s, self.due_s, self._start = camera, 1.0 / fps, 0.0, None

    def read(self):
        frame = self.camera.read()
        now = time.perf_counter()
        self._start = now if self._start is None else self._start
        self.due_s = self._start + frame.index * self.period_s
        time.sleep(max(0.0, self.due_s - now))
        return frame

    def delay_s(self) -> float:
        return time.perf_counter() - self.due_s


def play_live(args, localizer, video, opposite_video, openings, poses, frames_per_episode, shape
              ) -> tuple[dict, list, dict]:
    """The videos through ``live_estimates``: (summary, latencies ms of the frames where an
    update landed, every grasp's belief {(episode, grasp): PoseBelief} as the update left it).
    With ``--realtime`` the frames come at ``--fps`` and the summary adds how late they were."""
    statistics, updated_ms, beliefs, delays = LiveStatistics(), [], {}, []
    next_opening = iter(openings).__next__  # frames come in order: one opening each
    second_camera = None if opposite_video is None else OpenCVCamera(opposite_video, gelslim(scale=0.5))

    def keep(episode):  # the belief of the grasp an update just landed
        if localizer.grasps:
            beliefs[episode, localizer.grasps - 1] = localizer.beliefs[0]

    with OpenCVCamera(video, gelslim(scale=0.5)) as video_camera, CompilationCounter() as compiles:
        camera = PacedCamera(video_camera, args.fps) if args.realtime else video_camera
        for frame, estimate in live_estimates(camera, localizer, next_opening, second_camera=second_camera,
                                              gripper_pose=lambda frame: jaxlie.SE3(poses[frame.index]),
                                              read_ahead=0 if args.realtime else args.read_ahead):
            statistics.add(frame, estimate)
            if args.realtime:
                delays.append(camera.delay_s())
            episode = frame.index // frames_per_episode
            if estimate.updated:
                updated_ms.append(1e3 * estimate.latency_s)
                keep(episode)
            if (frame.index + 1) % frames_per_episode == 0:
                localizer.wait()  # an update still running lands before the object is put down elsewhere
                keep(episode)
                localizer.reset()
    localizer.close()
    if second_camera is not None:
        second_camera.close()
    statistics.recompilations = compiles.count
    for message in compiles.messages:
        print("recompiled:", message[:300])
    summary = statistics.summary()
    if args.realtime:
        delay_ms, period_ms = 1e3 * np.asarray(delays), 1e3 / args.fps
        summary["paced"] = {"fps": args.fps, "late_frames": int(np.sum(delay_ms > period_ms)),
                            "delay_ms": {"median": float(np.median(delay_ms)),
                                         "p95": float(np.percentile(delay_ms, 95)), "max": float(delay_ms.max())}}
    return summary, updated_ms, beliefs


def grasp_errors(beliefs: dict, records: dict, shape, truth_of) -> tuple[np.ndarray, np.ndarray]:
    """(E, G) errors of every grasp's sensor pose under the belief its update left, and its
    P(within 2 mm) (NaN where a grasp gave no estimate)."""
    errors, probability = np.full(shape, np.nan), np.full(shape, np.nan)
    for (e, g), belief in beliefs.items():
        t = e * shape[1] + g
        opening = jnp.float32(records["opening_mm"][t])
        T_world_sensor = sensor_pose(jaxlie.SE3(jnp.asarray(records["T_world_gripper"][t], jnp.float32)), opening)
        errors[e, g] = truth_of(t, np.asarray(belief.sensor_pose(T_world_sensor).wxyz_xyz))
        probability[e, g] = float(belief.probability_within())
    return errors, probability


def stage_by_stage(args, view, model, encoder, settings, records, opposite, shape, truth_of) -> dict:
    """The reference: the same grasps through ``touch_from_image`` and ``localize`` (continuing
    each episode's belief), timed per grasp."""

    episodes, grasps = shape
    beliefs, seconds, skipped = {}, [], 0
    for e in range(episodes):
        belief = None
        for g in range(grasps):
            t = e * grasps + g
            start = time.perf_counter()
            opening = jnp.float32(records["opening_mm"][t])
            T_world_gripper = jaxlie.SE3(jnp.asarray(records["T_world_gripper"][t], jnp.float32))
            T_world_sensor = sensor_pose(T_world_gripper, opening)
            touches = [touch_from_image(model, encoder, records["image"][t], float(opening))]
            T_world_touches = [T_world_sensor]
            if args.fingers == 2:
                touches.append(touch_from_image(model, encoder, opposite["image"][t], float(opening)))
                T_world_touches.append(opposite_sensor_pose(T_world_gripper, opening))
            try:
                belief = jax.block_until_ready(localize(view, touches, T_world_touches, belief=belief,
                                                        settings=settings))
            except ValueError:  # no contact in the episode's first grasp: nothing to localize yet
                skipped += 1
                continue
            seconds.append(time.perf_counter() - start)
            beliefs[e, g] = belief
    errors, probability = grasp_errors(beliefs, records, shape, truth_of)
    return {"ms_per_grasp": {"median": 1e3 * float(np.median(seconds[1:])),
                             "p95": 1e3 * float(np.percentile(seconds[1:], 95))},
            "first_call_s": seconds[0], "skipped": skipped, "per_grasp": per_grasp(errors, probability)}


def print_results(result: dict) -> None:
    live, reference, updated = result["live"], result["reference"], result["update_frame_ms"]
    episodes, grasps, fingers = result["episodes"], result["grasps_per_episode"], result["fingers"]
    loop = (f"live: {episodes} episodes x {grasps} grasps x {fingers} finger{'s' * (fingers > 1)}, each "
            f"{result['settle_frames']}+{result['hold_frames']} frames at rest + {result['gap_frames']} released")
    latency = live["latency_ms"]
    print(format_table(
        ["loop", "frames", "rate (Hz)", "latency median / p95 / max (ms)", "frames where an update landed: median / max (ms)",
         "recompilations"],
        [[loop, live["frames"], f"{live['rate_hz']:.1f}",
          f"{latency['median']:.1f} / {latency['p95']:.1f} / {latency['max']:.1f}",
          "-" if updated["median"] is None else f"{updated['median']:.1f} / {updated['max']:.1f}",
          live["recompilations"]]]))
    if "paced" in live:
        paced = live["paced"]
        print(f"paced at {paced['fps']:g} Hz ({'background' if result['background_update'] else 'synchronous'} "
              f"updates): {paced['late_frames']} of {live['frames']} frames came out more than a frame period "
              f"late; arrival to estimate median / p95 / max {paced['delay_ms']['median']:.1f} / "
              f"{paced['delay_ms']['p95']:.1f} / {paced['delay_ms']['max']:.1f} ms")
    headers = ["after grasp", "live: estimates", "median RMSE (mm)", "<= 2 mm", "mean P(<= 2 mm)"]
    rows = [[r["grasp"], r["estimates"], r["median_rmse_mm"], r["within_2mm"], r["mean_p_within_2mm"]]
            for r in result["per_grasp"]]
    if reference is not None:
        headers += ["reference: median RMSE (mm)", "<= 2 mm"]
        rows = [row + [r["median_rmse_mm"], r["within_2mm"]] for row, r in zip(rows, reference["per_grasp"])]
    print(format_table(headers, rows))
    print(f"start-up compile: {result['compile_s']:.1f} s; errors up to the {result['object']}'s "
          f"{result['symmetries']} symmetries; belief calibration: "
          f"{'stored' if result['calibrated'] else 'none (default)'}")
    if reference is not None:
        print(f"reference (stage by stage, localize() per grasp): {reference['ms_per_grasp']['median']:.1f} ms "
              f"median per grasp (first call, compiling: {reference['first_call_s']:.1f} s)")


def main() -> None:
    args = parse_args()
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    ((tactile_map, calibration),) = load_maps(args, model, encoder)
    name = tactile_map.object_id
    test = new_grasps_set(args, name, episodes=args.episodes, grasps=args.grasps, fingers=args.fingers)
    records, opposite, episodes, grasps = read_episodes(args, test, name)
    truth, means, covariances, symmetries = ground_truth(records, name, tactile_map.mm_per_px)

    def truth_of(t, T_estimate):
        return cloud_error(means[t], covariances[t], truth[t], T_estimate, symmetries)

    print(f"compiling the live programs ({name}: {len(tactile_map)} imprints) ...", flush=True)
    settings = BeliefSettings()
    localizer = Localizer([tactile_map], model, encoder, calibrations=[calibration], settings=settings,
                          live=LiveSettings(background_update=not args.synchronous_update))
    settle = localizer.live.settle_frames
    background = np.round(np.asarray(model.background) * 255).astype(np.uint8)
    video, opposite_video, openings, poses = write_videos(
        args, Path(args.work), name, records, opposite, background, settle, f"grasps-e{episodes}-g{grasps}")
    live, updated_ms, beliefs = play_live(args, localizer, video, opposite_video, openings, poses,
                                          grasps * (settle + args.hold + args.gap), (episodes, grasps))
    errors, probability = grasp_errors(beliefs, records, (episodes, grasps), truth_of)
    reference = None
    if not args.no_reference:
        view = LocalizationMap.from_tactile_map(tactile_map, calibration=calibration)
        reference = stage_by_stage(args, view, model, encoder, settings, records, opposite, (episodes, grasps),
                                   truth_of)
    result = {
        "object": name, "map_imprints": len(tactile_map), "test": str(test), "episodes": episodes,
        "grasps_per_episode": grasps, "fingers": args.fingers, "settle_frames": settle, "hold_frames": args.hold,
        "gap_frames": args.gap, "read_ahead": 0 if args.realtime else args.read_ahead, "video": str(video),
        "calibrated": calibration is not None,
        "background_update": not args.synchronous_update,
        "compile_s": localizer.compile_s, "live": live,
        "update_frame_ms": {"median": float(np.median(updated_ms)) if updated_ms else None,
                             "max": float(np.max(updated_ms)) if updated_ms else None},
        "per_grasp": per_grasp(errors, probability), "reference": reference, "symmetries": len(symmetries[1]),
        "seed": args.seed, "machine": machine_info()}
    print_results(result)
    if args.json:
        write_json(args.json, result)
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
