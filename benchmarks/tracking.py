"""Tracking between touches on simulated slip sequences, against re-localizing every frame.

An object slides and turns in the grasp (``tactojax simulate --protocol slip``: new grasps, then
up to 0.5 mm and 1 degree of slip per frame, 200 frames per sequence). Every frame goes through

- **tracking** (:class:`tactojax.localize.Tracker`, what ``localize-live`` runs): the first frame
  localized from nothing (the belief of that one touch: the grasp counts as settled at once),
  then followed, re-localized only when the fit degrades;
- **tracking from the true start**: the same, with the track started at the true pose of frame
  0 (``Tracker.start``), which separates how well it follows from how well it starts;
- **tracking from the fused belief**: the track started where a pose belief puts frame 0, as a
  robot would before lifting the object: ``--belief-grasps`` earlier grasps of the object where
  it stands (both fingers; a new-grasps episode at the sequence's object placement, simulated
  with a seed of its own) and the sequence's first frame itself are fused by
  :func:`tactojax.localize.localize` (with the object's symmetries), the touches related by the
  kinematics;
- **re-localizing every frame** (:class:`tactojax.localize.Localizer`: a new belief from each
  frame's touch alone, ``reset`` then ``fuse``).

Every frame goes with the gripper's pose at that frame (the slip sets record it).

Reported per mode: position error of the sensor pose (mm) over all frames, over the frames
whose touch is at least ``TrackingSettings.min_relocalize_px`` contact pixels and over the
smaller ones (a pinpoint contact says little about where it is), at the first and
the last frame; the drift at the end (error of the estimated motion since frame 0 against the
true motion), all up to the object's symmetries for a symmetric catalog object (the gum box);
re-localizations per frame; latency (median, and tracked frames alone) and the
sustained rate. A figure shows the median error against the frame index.

    python benchmarks/tracking.py --json tracking.json --figure tracking.png
    python benchmarks/tracking.py --quick     # smoke run: 2 sequences of 20 frames, a 20 mm map
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from tqdm.auto import tqdm

from tactojax import CompilationCounter
from tactojax.geometry import sensor_pose
from tactojax.io import open_dataset, read_test_grasps, resolve_encoder, resolve_shape_model
from tactojax.localize import (LiveSettings, LocalizationMap, Localizer, Touch, Tracker, TrackingSettings, localize,
                               touch_from_image)
from tactojax.localize.evaluation import load_test_episodes
from tactojax.objects import get_object
from tactojax.sensor import gelslim
from tactojax.simulate import GraspsProtocol, SlipProtocol, simulate_to_dataset

try:  # run as ``python benchmarks/tracking.py`` or as a module
    from benchmarks._common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                                    print_machine, write_json)
except ImportError:
    from _common import (add_common_arguments, add_map_arguments, format_table, load_maps, machine_info,
                         print_machine, write_json)

MODES = ("tracking", "tracking from the true start", "tracking from the fused belief", "re-localizing every frame")


def slip_sequences(work: Path, name: str, protocol: SlipProtocol, seed: int) -> dict[str, np.ndarray]:
    """The slip test set (simulated once, then read from ``work``), with true object-frame poses."""
    path = work / f"{name}-slip-s{protocol.sequences}-f{protocol.frames}-seed{seed}"
    if not (path / "manifest.json").exists():
        simulate_to_dataset(path, jax.random.key(seed), gelslim(scale=0.5), get_object(name), protocol)
    data = open_dataset(path).read(["image", "mask", "opening_mm", "T_world_gripper", "T_world_object", "sequence",
                                    "frame", "turn_rad"])
    data["contact_px"] = data.pop("mask").sum(axis=(1, 2))
    T_world_sensor = sensor_pose(jaxlie.SE3(jnp.asarray(data["T_world_gripper"])), jnp.asarray(data["opening_mm"]))
    T_object_sensor = jaxlie.SE3(jnp.asarray(data["T_world_object"])).inverse() @ T_world_sensor
    data["T_object_sensor"] = np.asarray(T_object_sensor.wxyz_xyz)
    return data


def belief_starts(work: Path, name: str, data: dict[str, np.ndarray], tactile_map, model, encoder, grasps: int,
                  seed: int) -> tuple[dict[int, np.ndarray], dict[int, float]]:
    """Per slip sequence, the pose of its frame 0 from a fused belief (see the module docstring).

    New-grasps episodes (``grasps`` grasps x 2 fingers, seed ``seed``), simulated at each object
    turn the sequences start from, give each sequence an episode at its object placement; its
    touches and the sequence's first frame are fused, related by their sensor poses (the
    kinematics: the object stands still until the sequence starts slipping); the episode's sensor
    poses and the frame's are all given in the object frame (the belief's world is the object's).

    Returns:
        {sequence: (7,) wxyz_xyz of frame 0's sensor pose, object frame} and {sequence: the
        belief's P(within 2 mm)}; a sequence without an episode at its placement has neither.
    """
    sequences = np.unique(data["sequence"])
    first = {int(q): np.flatnonzero((data["sequence"] == q) & (data["frame"] == 0))[0] for q in sequences}
    turn_of = {q: round(float(np.rad2deg(data["turn_rad"][row])), 3) for q, row in first.items()}
    episodes_at = {}  # turn -> (episodes, their object placements)
    for turn in sorted(set(turn_of.values())):
        count = sum(t == turn for t in turn_of.values())
        path = work / f"{name}-belief-grasps-turn{turn:g}-e{count}-g{grasps}-seed{seed}"
        if not (path / "manifest.json").exists():
            protocol = GraspsProtocol(episodes=count, grasps_per_episode=grasps, fingers=2, turns_deg=(turn,))
            try:
                simulate_to_dataset(path, jax.random.key(seed), gelslim(scale=0.5), get_object(name), protocol)
            except ValueError as error:  # the new-grasps protocol finds no grasp at this placement
                print(f"no belief start for the sequences at turn {turn:g} deg: {error}")
                continue
        episodes, _ = load_test_episodes(path, name, model, encoder, progress=False)
        placement = read_test_grasps(path, ["T_world_object"], object_id=name)["T_world_object"][:: grasps * 2]
        episodes_at[turn] = [episodes, placement, list(range(len(placement)))]
    view = LocalizationMap.from_tactile_map(tactile_map)  # the catalog object's symmetries

    starts, confidence = {}, {}
    for sequence, row in first.items():
        if turn_of[sequence] not in episodes_at:
            continue
        episodes, placement, unused = episodes_at[turn_of[sequence]]
        e = unused.pop(0)
        if not np.allclose(placement[e], data["T_world_object"][row], atol=1e-3):
            raise RuntimeError(f"episode {e} does not stand where sequence {sequence} starts")
        touches, poses = [], []
        for g in range(grasps):
            for f in range(2):
                touches.append(Touch(heightmap=episodes.heightmaps[e, g, f], mask=episodes.masks[e, g, f],
                                     feature=episodes.features[e, g, f], opening=episodes.openings[e, g]))
                poses.append(jax.tree.map(lambda x: x[e, g, f], episodes.T_object_sensor))
        T_first = jaxlie.SE3(jnp.asarray(data["T_object_sensor"][row]))  # the kinematics, relative to the episode
        touches.append(touch_from_image(model, encoder, data["image"][row], float(data["opening_mm"][row])))
        try:
            belief = localize(view, touches, poses + [T_first])
        except ValueError as error:  # no touch with contact
            print(f"no belief start for sequence {sequence}: {error}")
            continue
        starts[sequence] = np.asarray(belief.sensor_pose(T_first).wxyz_xyz)
        confidence[sequence] = float(belief.probability_within())
    return starts, confidence


class EveryFrame:
    """Re-localize every frame: a new belief from the frame's touch alone."""

    def __init__(self, localizer: Localizer):
        self.localizer = localizer

    def __call__(self, image, opening_mm, T_world_gripper):
        self.localizer.reset()
        return self.localizer.fuse(image, opening_mm, T_world_gripper)


def run_sequence(estimator, images, openings, grippers) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(F, 7) estimated poses (NaN without one), (F,) latency s, (F,) tracked, (F,) relocalized."""
    poses = np.full((len(images), 7), np.nan)
    latency, tracked, relocalized = np.zeros(len(images)), np.zeros(len(images), bool), np.zeros(len(images), bool)
    for k, (image, opening, gripper) in enumerate(zip(images, openings, grippers)):
        before = getattr(estimator, "relocalizations", k)
        estimate = estimator(image, float(opening), jaxlie.SE3(gripper))
        latency[k], tracked[k] = estimate.latency_s, estimate.tracked
        relocalized[k] = getattr(estimator, "relocalizations", k + 1) > before
        if estimate.T_object_sensor is not None:
            poses[k] = np.asarray(estimate.T_object_sensor.wxyz_xyz)
    return poses, latency, tracked, relocalized


def errors(poses: np.ndarray, truth: np.ndarray, symmetries: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, float]:
    """(F,) position error, mm (NaN without an estimate), and the drift at the last frame: the
    error of the estimated motion since frame 0 against the true one, mm.

    Both are up to the object's symmetries, ``(G, 3, 3)`` rotations and ``(G, 3)`` translations
    of object-frame transforms, identity first: the pose ``g @ T`` of a symmetric object is as
    right as ``T``, so each frame's error is the smallest over ``g``, and the drift compares the
    estimated motion with the true motion seen through the symmetry nearest the last frame.
    (NumPy, so that the benchmark's loop compiles nothing.)
    """
    rotations, translations = symmetries
    copies = np.einsum("gij,fj->gfi", rotations, truth[:, 4:]) + translations[:, None]  # (G, F, 3)
    per_copy = np.linalg.norm(poses[None, :, 4:] - copies, axis=-1)  # (G, F)
    position = np.where(np.isnan(poses[:, 4]), np.nan, np.min(np.nan_to_num(per_copy, nan=np.inf), axis=0))
    best = int(np.argmin(np.nan_to_num(per_copy[:, -1], nan=np.inf)))
    drift = np.linalg.norm((poses[-1, 4:] - poses[0, 4:]) - (copies[best, -1] - copies[best, 0]))
    return position, float(drift)


def _nanmedian(values: np.ndarray) -> float | None:
    return float(np.nanmedian(values)) if np.isfinite(values).any() else None


def _cell(value: float | None) -> float | str:
    return "-" if value is None else value


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_map_arguments(parser)
    parser.add_argument("--sequences", type=int, default=10)
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--belief-grasps", type=int, default=3,
                        help="grasps (both fingers) fused before each sequence for the belief's start (default 3)")
    parser.add_argument("--search-mm", type=float, default=TrackingSettings().search_mm,
                        help="TrackingSettings.search_mm: in-plane shift of the extra ICP starts (0: none)")
    parser.add_argument("--figure", metavar="PATH", help="median error against the frame index (.png)")
    add_common_arguments(parser, quick="2 sequences of 20 frames, 1 belief grasp, a 20 mm map", seed=2026,
                         seed_help="slip test set (not tuned on; the belief's grasps use seed + 1)")
    args = parser.parse_args()
    if args.quick:
        args.sequences, args.frames, args.belief_grasps = min(args.sequences, 2), min(args.frames, 20), 1
    return args


def run_modes(args, data, starts, tracker, localizer, symmetries) -> tuple[dict, list]:
    """Every sequence through every mode (:data:`MODES`), recompilations counted: per mode the
    lists of per-sequence errors, drift, latency, tracked and re-localized frames; and per
    sequence its frames' true contact pixels."""
    results = {mode: {"position_mm": [], "drift_mm": [], "latency_s": [], "tracked": [], "relocalized": [],
                      "sequence_index": []} for mode in MODES}
    contact_px = []  # per sequence, (F,) true contact pixels
    counter = CompilationCounter()
    with counter:
        for index, sequence in enumerate(tqdm(np.unique(data["sequence"]), desc="sequences", unit="sequence")):
            rows = np.flatnonzero(data["sequence"] == sequence)
            rows = rows[np.argsort(data["frame"][rows])]
            images, openings, truth = data["image"][rows], data["opening_mm"][rows], data["T_object_sensor"][rows]
            grippers = data["T_world_gripper"][rows].astype(np.float32)
            contact_px.append(data["contact_px"][rows])
            for mode in MODES:
                estimator = estimator_of(mode, args.object_id, int(sequence), truth[0], starts, tracker, localizer)
                if estimator is None:
                    continue
                poses, latency, tracked, relocalized = run_sequence(estimator, images, openings, grippers)
                position, drift = errors(poses, truth, symmetries)
                for name, value in (("position_mm", position), ("drift_mm", drift), ("latency_s", latency),
                                    ("tracked", tracked), ("relocalized", relocalized), ("sequence_index", index)):
                    results[mode][name].append(value)
    results["recompilations"] = counter.count
    return results, contact_px


def estimator_of(mode: str, object_id: str, sequence: int, true_start, starts: dict, tracker, localizer):
    """The estimator a mode runs, reset and started as the mode says (None: no belief start)."""
    if mode == "re-localizing every frame":
        return EveryFrame(localizer)
    tracker.reset()
    if mode == "tracking from the true start":
        tracker.start(object_id, jaxlie.SE3(jnp.asarray(true_start, jnp.float32)))
    if mode == "tracking from the fused belief":
        if sequence not in starts:
            return None
        tracker.start(object_id, jaxlie.SE3(jnp.asarray(starts[sequence], jnp.float32)))
    return tracker


def summarize(results: dict, contact_px: list) -> tuple[dict, np.ndarray]:
    """Per mode that ran, the JSON summary (errors, drift, re-localizations, latency, rate); and
    the (S, F) frames too small to localize."""
    all_small = np.stack(contact_px) < TrackingSettings().min_relocalize_px  # (S, F) touches too small to localize
    summary = {}
    for mode in MODES:
        result = results[mode]
        if not result["position_mm"]:
            continue
        position = np.stack(result["position_mm"])  # (S', F): the sequences the mode ran
        small = all_small[result["sequence_index"]]
        latency, tracked = np.stack(result["latency_s"]), np.stack(result["tracked"])
        relocalized = np.stack(result["relocalized"])
        summary[mode] = {
            "median_error_mm": float(np.nanmedian(position)),
            "median_error_larger_touches_mm": _nanmedian(position[~small]),
            "median_error_small_touches_mm": _nanmedian(position[small]),
            "first_frame_error_mm": float(np.nanmedian(position[:, 0])),
            "last_frame_error_mm": float(np.nanmedian(position[:, -1])),
            "end_drift_mm": float(np.nanmedian(result["drift_mm"])),
            "relocalized_fraction": float(relocalized[:, 1:].mean()),
            "median_latency_ms": 1e3 * float(np.median(latency)),
            "tracked_latency_ms": 1e3 * float(np.median(latency[tracked])) if tracked.any() else None,
            "rate_hz": float(latency.size / latency.sum()),
            "median_error_by_frame_mm": np.nanmedian(position, axis=0).tolist(),
            "sequences": len(position),
        }
    return summary, all_small


def print_results(args, summary: dict, all_small: np.ndarray, contact_px: list, recompilations: int,
                  symmetries: int) -> None:
    minimum = TrackingSettings().min_relocalize_px
    rows = [[f"{mode} ({entry['sequences']})" if entry["sequences"] < len(all_small) else mode,
             entry["median_error_mm"], _cell(entry["median_error_larger_touches_mm"]),
             _cell(entry["median_error_small_touches_mm"]), entry["first_frame_error_mm"],
             entry["last_frame_error_mm"], entry["end_drift_mm"], f"{100 * entry['relocalized_fraction']:.1f} %",
             entry["median_latency_ms"], _cell(entry["tracked_latency_ms"]), entry["rate_hz"]]
            for mode, entry in summary.items()]
    print(f"{100 * all_small.mean():.0f} % of the frames touch fewer than {minimum} contact "
          f"pixels (median contact {int(np.median(np.stack(contact_px)))} px)")
    print(format_table(["mode", "median error mm", f"touches >= {minimum} px", "smaller", "frame 0 mm",
                        "last frame mm", "end drift mm", "re-localized", "median ms", "tracked ms", "rate Hz"], rows))
    print(f"recompilations during the run: {recompilations}")
    print("errors are sensor positions in the object frame against the simulator's truth"
          + (f", up to the {args.object_id}'s {symmetries} symmetries" if symmetries > 1 else "")
          + "; the drift is the error of the estimated motion from frame 0 to the last")


def save_figure(args, summary: dict, results: dict, protocol: SlipProtocol, symmetric: bool) -> None:
    """The median error over sequences against the frame index, one line per mode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(7, 4), constrained_layout=True)
    for mode in summary:
        axis.plot(np.nanmedian(np.stack(results[mode]["position_mm"]), axis=0), label=mode)
    axis.set_xlabel("frame")
    axis.set_ylabel("median position error over sequences (mm)")
    axis.set_yscale("log")
    axis.set_title(f"{args.object_id}: {args.sequences} slip sequences, up to {protocol.max_step_mm} mm and "
                   f"{protocol.max_step_deg} deg per frame" + (" (errors up to symmetry)" if symmetric else ""),
                   fontsize=10)
    axis.legend()
    figure.savefig(args.figure, dpi=120)
    print(f"figure: {args.figure}")


def main() -> None:
    args = parse_args()
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    print_machine()
    ((tactile_map, _),) = load_maps(args, model, encoder)
    args.object_id = tactile_map.object_id
    work = Path(args.work)
    protocol = SlipProtocol(sequences=args.sequences, frames=args.frames)
    data = slip_sequences(work, args.object_id, protocol, args.seed)
    group = get_object(args.object_id).symmetry.transforms()
    symmetries = (np.asarray(group.rotation().as_matrix()), np.asarray(group.translation()))
    print(f"map: {len(tactile_map)} imprints; {args.sequences} slip sequences of {args.frames} frames")
    starts, start_confidence = belief_starts(work, args.object_id, data, tactile_map, model, encoder,
                                             args.belief_grasps, args.seed + 1)
    print(f"belief starts: {len(starts)} of {args.sequences} sequences have an episode at their placement")
    # A slip sequence's first frame is its grasp: it updates the belief at once (no settling).
    tracker = Tracker([tactile_map], model, encoder, tracking=TrackingSettings(search_mm=args.search_mm),
                      live=LiveSettings(settle_frames=1))
    localizer = Localizer([tactile_map], model, encoder)
    print(f"compiled: tracker {tracker.compile_s:.1f} s (its localizer included), localizer {localizer.compile_s:.1f} s")
    results, contact_px = run_modes(args, data, starts, tracker, localizer, symmetries)
    summary, all_small = summarize(results, contact_px)
    print_results(args, summary, all_small, contact_px, results["recompilations"], len(symmetries[1]))
    if args.figure:
        save_figure(args, summary, results, protocol, len(symmetries[1]) > 1)
    if args.json:
        write_json(args.json, {"machine": machine_info(), "object": args.object_id, "encoder": args.encoder,
                               "search_mm": args.search_mm, "sequences": args.sequences, "frames": args.frames,
                               "seed": args.seed, "recompilations": results["recompilations"],
                               "errors_up_to_symmetries": len(symmetries[1]),
                               "small_touch_fraction": float(all_small.mean()),
                               "belief_grasps": args.belief_grasps,
                               "belief_start_p_within_2mm": start_confidence,
                               "compile_s": {"tracker": tracker.compile_s, "localizer": localizer.compile_s},
                               "modes": summary})
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
