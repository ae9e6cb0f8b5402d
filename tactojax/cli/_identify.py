"""``tactojax identify MAP...``: which object is in the hand, from one touch (paper section VII)."""

from __future__ import annotations

from tactojax.cli._map import DEFAULT_MODEL
from tactojax.cli._maps import add_encoder_argument, load_maps_with_features
from tactojax.cli._table import format_table, write_json
from tactojax.localize._identify_episodes import OBJECT_TOLERANCE


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "identify", help="object identification among several maps (held-out touches)",
        description="Every imprint of every map is held out of its own map and identified as the "
                    "object whose map holds the most similar imprint (paper section VII); prints "
                    "top-1 accuracy and the confusion matrix, and saves it as a figure.")
    parser.add_argument("maps", nargs="+",
                        help="tactile maps (.npz) of different objects, or map catalogs (`tactojax map-catalog`)")
    add_encoder_argument(parser)
    parser.add_argument("--figure", metavar="PNG", default="identification.png",
                        help="confusion-matrix figure (with --test: after the last grasp)")
    parser.add_argument("--json", metavar="PATH", help="write the metrics as JSON")
    new = parser.add_argument_group("new grasps (instead of leave-one-out)")
    new.add_argument("--test", nargs="+", metavar="DIR",
                     help="new-grasps test sets (`tactojax simulate OBJECT --protocol grasps`) of objects among the "
                          "maps: each episode's grasps fused by every map's pose belief, P(object) from their "
                          "likelihoods, top-1 after k = 1..K grasps")
    new.add_argument("--fingers", type=int, choices=[1, 2], default=2, help="fingers fused per grasp (default 2)")
    new.add_argument("--model", default=DEFAULT_MODEL, help=f"shape model for the test images (default {DEFAULT_MODEL})")
    new.add_argument("--object-tolerance", type=float, default=OBJECT_TOLERANCE, metavar="P",
                     help="P(object) a grasp may drop, as the live localizer: after each grasp the least probable "
                          f"maps that together hold at most P are no longer weighed (default {OBJECT_TOLERANCE}; "
                          "0: every map)")
    parser.set_defaults(run=run)


def run(args) -> int:
    from tactojax.io import expand_catalogs
    from tactojax.localize.evaluation import evaluate_identification
    from tactojax.viz import confusion_figure, save_png

    args.maps = expand_catalogs(args.maps)
    if len(args.maps) < 2:
        raise ValueError("identification needs the maps of at least two objects")
    if args.test:
        return run_new_grasps(args)
    maps, _ = load_maps_with_features(args.maps, args.encoder)
    result = evaluate_identification(maps, progress=True)
    summary = result.summary()
    confusion = result.confusion()
    names = list(result.object_ids)
    print(f"identification top-1: {100 * result.accuracy():.1f} % of {len(result.true)} held-out touches")
    print(format_table(["true \\ identified", *names, "top-1"],
                       [[name, *map(int, confusion[i]), f"{100 * summary['per_object_top1'][name]:.1f} %"]
                        for i, name in enumerate(names)]))
    save_png(confusion_figure(confusion, names), args.figure)
    print(f"figure: {args.figure}")
    if args.json:
        write_json(args.json, summary)
    return 0


def run_new_grasps(args) -> int:
    """``identify MAP... --test DIR...``: P(object) from every map's belief over each episode."""
    import jax
    import numpy as np

    from tactojax.cli._maps import maps_and_query_encoder, stacked_localization_maps
    from tactojax.io import read_test_grasps, resolve_shape_model
    from tactojax.localize.evaluation import load_test_episodes
    from tactojax.localize import calibration_to_json
    from tactojax.localize.evaluation import identify_episodes, maps_in_play
    from tactojax.viz import confusion_figure, save_png

    maps, encoder = maps_and_query_encoder(args.maps, args.encoder)
    names = [m.object_id for m in maps]
    model = resolve_shape_model(args.model)
    catalog, _ = stacked_localization_maps(args.maps, maps, args.encoder, shared=True)
    calibration = jax.tree.map(lambda x: x[0], catalog.calibration)  # the maps' median: one calibration, so that evidences compare
    correct, probability, identified, weighed = {}, {}, {}, {}  # object -> (E, G) arrays
    for directory in args.test:
        for name in sorted(set(read_test_grasps(directory, ["opening_mm"])["object_id"].tolist())):
            if name not in names:
                raise ValueError(f"the test set {directory} holds {name!r}, which none of the maps is ({names})")
            episodes, recorded = load_test_episodes(directory, name, model, encoder)
            if args.fingers > recorded:
                raise ValueError(f"--fingers {args.fingers}: {directory} records {recorded} finger per grasp")
            p = identify_episodes(catalog, episodes, fingers=args.fingers, calibration=calibration,
                                  object_tolerance=args.object_tolerance, progress=True)
            identified[name] = np.argmax(p, axis=-1)
            correct[name] = identified[name] == names.index(name)
            probability[name] = p[..., names.index(name)]
            weighed[name] = maps_in_play(p, args.object_tolerance).sum(axis=-1)
    grasps = min(c.shape[1] for c in correct.values())
    rows, results = [], []
    for k in range(grasps):
        hits = np.concatenate([c[:, k] for c in correct.values()])
        true_p = np.concatenate([p[:, k] for p in probability.values()])
        maps_weighed = float(np.mean(np.concatenate([w[:, k] for w in weighed.values()])))
        results.append({"grasps": k + 1, "fingers": args.fingers, "count": int(len(hits)),
                        "top1": float(np.mean(hits)), "mean_probability_of_truth": float(np.mean(true_p)),
                        "mean_maps_weighed": maps_weighed,
                        "per_object_top1": {n: float(np.mean(c[:, k])) for n, c in correct.items()}})
        rows.append([k + 1, args.fingers, len(hits), f"{100 * np.mean(hits):.1f} %", float(np.mean(true_p)),
                     maps_weighed, *(f"{100 * np.mean(c[:, k]):.0f} %" for c in correct.values())])
    print(f"identification among {len(names)} objects, P(object) from the pose beliefs of the maps in play "
          f"(object tolerance {args.object_tolerance})")
    print(format_table(["grasps", "fingers", "episodes", "top-1", "mean P(true object)", "maps weighed", *correct],
                       rows))
    confusion = np.zeros((len(names), len(names)), int)  # [true, identified] after the last grasp
    for name, choice in identified.items():
        np.add.at(confusion[names.index(name)], choice[:, grasps - 1], 1)
    save_png(confusion_figure(confusion, names, counted="episodes"), args.figure)
    print(f"figure: {args.figure} (confusion after {grasps} grasps)")
    if args.json:
        write_json(args.json, {"objects": names, "test": args.test, "calibration": calibration_to_json(calibration),
                               "object_tolerance": args.object_tolerance,
                               "results": results, "confusion": {"grasps": grasps, "true_by_identified": confusion.tolist()}})
    return 0
