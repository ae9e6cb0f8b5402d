"""``tactojax demo``: the whole paper end to end on built-in objects, then the pose belief, in a few minutes.

1. Local shape (section IV): simulated calibration touches of the five calibration shapes; the
   bundled ``fast`` model recovers their heightmaps from the images (Table I's measure).
2. Tactile maps (section V): the mapping protocol on three household objects; every imprint's
   heightmap is *predicted* by the bundled model and placed by the kinematics.
3. Localization (section VI): leave-one-out RANDOM / CTI / CTI-ICP-5 with the ImageNet
   EfficientNet-Lite0 features (Table III; ``--methods`` adds CTI-ICP-1), with error histograms.
4. Identification (section VII): each held-out touch is assigned to the object whose map holds
   the most similar imprint (confusion matrix).
5. The pose belief (the library's answer, beyond the paper) on *new* grasps, off the mapping
   grid: episodes of grasps with both fingers while the object stays put, fused grasp by grasp
   by the kinematics; its error and its predicted P(within 2 mm) after 1 and 3 grasps, and a
   figure of where it puts the sensor.
6. Active touch on the simulated robot cell: the live localizer fuses each grasp of one object
   and chooses the next by expected gain in P(within 2 mm), until it is sure or after 3 grasps;
   the grasps chosen and the belief after each, and a figure of both.

Tables are printed, figures saved as PNG and everything can be written as JSON.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import jax
from tqdm.auto import tqdm

from tactojax.cli._map import DEFAULT_MODEL
from tactojax.cli._table import format_table, write_json
from tactojax.io import DEFAULT_ENCODER

DEMO_OBJECTS = ("scissors", "tape_roll", "gum_box")
DEMO_METHODS = ("random", "cti", "cti-icp-5")
DEMO_ACTIVE_OBJECT = "gum_box"


def add_parser(commands) -> None:
    parser = commands.add_parser("demo", help="the whole paper end to end on built-in objects",
                                 description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="tactojax-demo", help="output folder (default ./tactojax-demo)")
    parser.add_argument("--objects", nargs="+", default=list(DEMO_OBJECTS))
    parser.add_argument("--grid-mm", type=float, default=15.0, help="mapping grid, mm (default 15; the paper: 10)")
    parser.add_argument("--yaws-deg", type=float, nargs="+", default=[0.0],
                        help="grasp yaws, degrees (default 0; the paper: 0 20 -20)")
    parser.add_argument("--scale", type=float, default=0.5, help="sensor resolution factor (default 0.5)")
    parser.add_argument("--calibration-touches", type=int, default=20, help="per calibration shape")
    parser.add_argument("--queries", type=int, default=60, help="held-out touches per object for localization")
    parser.add_argument("--methods", default=",".join(DEMO_METHODS),
                        help="leave-one-out methods: the paper's baselines (step 3)")
    parser.add_argument("--episodes", type=int, default=4,
                        help="new-grasps episodes per object for the belief (step 5; default 4)")
    parser.add_argument("--grasps", type=int, default=3,
                        help="grasps per episode, both fingers each (step 5; default 3)")
    parser.add_argument("--active-object", default=DEMO_ACTIVE_OBJECT,
                        help=f"the object of the active episode (step 6; default {DEMO_ACTIVE_OBJECT}, else the first)")
    parser.add_argument("--active-grasps", type=int, default=3,
                        help="grasps of the active episode at most (step 6; default 3, 0 skips it)")
    parser.add_argument("--active-candidates", type=int, default=32,
                        help="grasps proposed per choice (step 6; default 32)")
    parser.add_argument("--model", default=DEFAULT_MODEL, help="shape model")
    parser.add_argument("--encoder", default=DEFAULT_ENCODER, help="feature encoder")
    parser.add_argument("--json", metavar="PATH", help="also write every table as JSON")
    parser.add_argument("--seed", type=int, default=0)
    parser.set_defaults(run=run)


def run(args) -> int:
    from tactojax.io import resolve_encoder, resolve_shape_model
    from tactojax.sensor import gelslim

    start = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model, encoder = resolve_shape_model(args.model), resolve_encoder(args.encoder)
    spec = gelslim(scale=args.scale)
    if abs(spec.mm_per_px - model.mm_per_px) > 1e-6:
        raise ValueError(f"the shape model is for {model.mm_per_px} mm/px, the demo sensor has {spec.mm_per_px}: "
                         "pass --scale to match it")
    steps = {}
    steps["local_shape"] = time.perf_counter()
    report = {"local_shape": _local_shape(args, spec, model, out)}
    steps["maps"] = time.perf_counter()
    maps, report["maps"] = _maps(args, spec, model, encoder, out)
    steps["localization"] = time.perf_counter()
    report["localization"] = _localization(args, maps, out)
    steps["identification"] = time.perf_counter()
    report["identification"] = _identification(maps, out)
    steps["belief"] = time.perf_counter()
    report["belief"] = _belief(args, spec, model, encoder, maps, out)
    steps["active"] = time.perf_counter()
    report["active"] = _active(args, spec, model, encoder, maps, out)
    report["seconds"] = time.perf_counter() - start
    ends = [*list(steps.values())[1:], start + report["seconds"]]
    report["step_seconds"] = {name: end - begin for (name, begin), end in zip(steps.items(), ends)}
    print(f"\ndemo finished in {report['seconds']:.0f} s ("
          + ", ".join(f"{name.replace('_', ' ')} {seconds:.0f} s" for name, seconds in report["step_seconds"].items())
          + f"); figures and maps in {out}/")
    if args.json:
        write_json(args.json, report)
    return 0


def _local_shape(args, spec, model, out: Path) -> dict:
    """Section IV: heightmaps of simulated calibration touches recovered by the shape model."""
    import numpy as np

    from tactojax.cli._shape_report import print_shape_report
    from tactojax.io import load_shape_data
    from tactojax.objects import CALIBRATION_SHAPES, get_object
    from tactojax.shape import evaluate_shape_model, predict_batch
    from tactojax.simulate import CalibrationProtocol, simulate_to_dataset
    from tactojax.viz import shape_examples_figure

    path = out / "datasets" / "calibration"
    shutil.rmtree(path, ignore_errors=True)
    print(f"1/6 local shape: simulating {args.calibration_touches} touches of each calibration shape")
    for index, name in enumerate(CALIBRATION_SHAPES):
        simulate_to_dataset(path, jax.random.key(args.seed + index), spec, get_object(name),
                            CalibrationProtocol(touches=args.calibration_touches), progress=False)
    data = load_shape_data(path)
    errors = evaluate_shape_model(model, data, progress=False)
    summary = print_shape_report(errors, data.object_ids, title=f"local shape with {args.model} (paper: 0.060 mm)")
    rows = [int(np.flatnonzero(data.object_ids == name)[0]) for name in dict.fromkeys(data.object_ids.tolist())]
    padded = rows + [rows[-1]] * (32 - len(rows))  # reuse the evaluation's compiled batch size
    predicted = np.asarray(predict_batch(model, data.images_float(padded))[0])[: len(rows)]
    figure = shape_examples_figure(data.images[rows], data.heightmaps[rows], predicted, out / "demo_local_shape.png",
                                   mm_per_px=spec.mm_per_px, titles=[str(data.object_ids[r]) for r in rows])
    print(f"figure: {figure}")
    return {"errors": summary, "figure": str(figure)}


def _maps(args, spec, model, encoder, out: Path):
    """Section V: simulate the mapping protocol, build each map from predicted heightmaps."""
    from tactojax.features import encode_images
    from tactojax.io import open_dataset, read_grasps, save_tactile_map
    from tactojax.mapping import build_tactile_map, stitched_point_cloud, surface_distance
    from tactojax.objects import get_object
    from tactojax.simulate import MappingProtocol, simulate_to_dataset
    from tactojax.viz import imprint_figure, tactile_map_figure

    protocol = MappingProtocol(grid_mm=args.grid_mm, yaws_deg=tuple(args.yaws_deg))
    maps, rows, records = [], [], {}
    (out / "maps").mkdir(parents=True, exist_ok=True)
    print(f"\n2/6 tactile maps: {protocol.grid_mm:g} mm grid, yaws {list(protocol.yaws_deg)} deg")
    for index, name in enumerate(args.objects):
        try:
            obj = get_object(name)
        except ImportError as error:
            print(f"skipping {name}: {error}")
            continue
        dataset = out / "datasets" / name
        shutil.rmtree(dataset, ignore_errors=True)  # the demo starts each object afresh
        started = time.perf_counter()
        simulate_to_dataset(dataset, jax.random.key(args.seed + 100 + index), spec, obj, protocol)
        records[name] = open_dataset(dataset).read()
        grasps = read_grasps(dataset)
        tactile_map = build_tactile_map(model, grasps["images"], grasps["T_world_gripper"], grasps["openings"], name,
                                        T_world_object=grasps["T_world_object"], points_per_imprint=512)
        tactile_map = tactile_map.with_features(encode_images(encoder, tactile_map.stored_images()))
        save_tactile_map(out / "maps" / f"{name}.npz", tactile_map, metadata={"model": args.model, "encoder": args.encoder})
        points, _ = stitched_point_cloud(tactile_map)
        distance = surface_distance(obj, points)["mean"] if len(points) else float("nan")
        rows.append([name, len(tactile_map), int(tactile_map.imprint_valid.sum()), distance,
                     time.perf_counter() - started])
        maps.append(tactile_map)
    headers = ["object", "imprints", "with contact", "map to surface (mm)", "time (s)"]
    print(format_table(headers, rows))
    figure = imprint_figure(records, spec.mm_per_px, out / "demo_imprints.png")
    first = maps[0]
    cloud, _ = stitched_point_cloud(first, voxel_mm=0.5)
    map_figure = tactile_map_figure(cloud, out / "demo_map.png", title=f"tactile map of {first.object_id}")
    print(f"figures: {figure}, {map_figure}")
    return maps, {"rows": [dict(zip(headers, row)) for row in rows], "figures": [str(figure), str(map_figure)]}


def _localization(args, maps, out: Path) -> dict:
    """Section VI: leave-one-out localization, Table III and histograms."""
    import numpy as np

    from tactojax.cli._maps import histogram_panel
    from tactojax.localize.evaluation import evaluate_localization
    from tactojax.localize._baselines import parse_method
    from tactojax.viz import localization_histogram_figure, save_png

    methods = [parse_method(m).name for m in args.methods.split(",") if m.strip()]
    print(f"\n3/6 localization: leave-one-out, up to {args.queries} held-out touches per object")
    rows, histograms, payload = [], {}, {}
    for tactile_map in maps:
        valid = np.flatnonzero(np.asarray(tactile_map.imprint_valid))
        if len(valid) > args.queries:
            valid = np.sort(np.random.default_rng(args.seed).choice(valid, args.queries, replace=False))
        results = evaluate_localization(jax.random.key(args.seed), tactile_map, methods,
                                        queries=valid, progress=True)
        payload[tactile_map.object_id] = {m: r.summary() for m, r in results.items()}
        title, panel = histogram_panel(tactile_map, results)
        histograms[title] = panel
        rows.append([tactile_map.object_id, *(f"{np.median(r.rmse):.1f} ({np.median(r.symmetric_rmse):.1f})"
                                              for r in results.values())])
    print("median RMSE, mm (symmetry-aware in brackets); the paper: CTI 10-20, CTI-ICP-5 6.1-22.6")
    print(format_table(["object", *methods], rows))
    figure = save_png(localization_histogram_figure(histograms), out / "demo_localization.png")
    print(f"figure: {figure}")
    return {"objects": payload, "figure": str(figure)}


def _identification(maps, out: Path) -> dict:
    """Section VII: which object is in the hand, from one held-out touch."""
    from tactojax.localize.evaluation import evaluate_identification
    from tactojax.viz import confusion_figure, save_png

    print("\n4/6 identification: every touch held out of its own map")
    result = evaluate_identification(maps)
    confusion, names = result.confusion(), list(result.object_ids)
    print(f"top-1 {100 * result.accuracy():.1f} % of {len(result.true)} touches")
    print(format_table(["true \\ identified", *names], [[n, *map(int, confusion[i])] for i, n in enumerate(names)]))
    figure = save_png(confusion_figure(confusion, names), out / "demo_identification.png")
    print(f"figure: {figure}")
    return {**result.summary(), "figure": str(figure)}


def _belief(args, spec, model, encoder, maps, out: Path) -> dict:
    """Beyond the paper: the pose belief on new grasps, fused over the grasps of each episode."""
    import numpy as np

    from tactojax.io import stored_surface
    from tactojax.localize import LocalizationMap, Touch, localize
    from tactojax.localize.evaluation import load_test_episodes
    from tactojax.objects import get_object
    from tactojax.simulate import GraspsProtocol, simulate_to_dataset
    from tactojax.viz import belief_figure, save_png

    if args.episodes < 1 or args.grasps < 1:
        raise ValueError("--episodes and --grasps must be at least 1")
    protocol = GraspsProtocol(episodes=args.episodes, grasps_per_episode=args.grasps, fingers=2,
                              turns_deg=(0.0, 180.0))
    shown = sorted({1, args.grasps})
    print(f"\n5/6 the pose belief on new grasps: {args.episodes} episodes of {args.grasps} grasps per object, off "
          "the mapping grid, both fingers; each grasp fused by the kinematics (the default calibration; "
          "`tactojax map-catalog --calibrate 64` or `calibrate-belief` fits a map's own on grasps of its object)")
    rows, payload, examples, curves = [], {}, {}, {}
    for index, tactile_map in enumerate(maps):
        name = tactile_map.object_id
        dataset = out / "datasets" / f"{name}-new-grasps"
        shutil.rmtree(dataset, ignore_errors=True)
        simulate_to_dataset(dataset, jax.random.key(args.seed + 200 + index), spec, get_object(name), protocol,
                            progress=False)
        episodes, _ = load_test_episodes(dataset, name, model, encoder, progress=False)
        view = LocalizationMap.from_tactile_map(tactile_map, surface=stored_surface(out / "maps" / f"{name}.npz"))
        symmetry = (view.symmetries, view.symmetry_axis, view.symmetry_centre)
        count = int(episodes.openings.shape[0])
        error, within = np.full((count, args.grasps), np.inf), np.zeros((count, args.grasps))
        snapshots = [{} for _ in range(count)]  # per episode: {grasps: (positions, probabilities)}
        for e in tqdm(range(count), desc=f"{name} episodes", leave=False):
            episode = jax.tree.map(lambda x: x[e], episodes)
            belief = None
            for g in range(args.grasps):
                if belief is None and not np.any(np.asarray(episode.masks[g])):
                    continue  # nothing felt yet: no estimate (an infinite error, P 0)
                touches = [Touch(heightmap=episode.heightmaps[g, f], mask=episode.masks[g, f],
                                 feature=episode.features[g, f], opening=episode.openings[g]) for f in range(2)]
                # The sensor poses of the kinematics, here in the object's frame: only how they
                # relate the touches reaches the belief.
                belief = localize(view, touches, jax.tree.map(lambda x: x[g], episode.T_object_sensor),
                                  belief=belief)
                error[e, g], within[e, g], positions = jax.device_get(_score_belief(symmetry, belief, episode, g))
                if g + 1 in shown:
                    snapshots[e][g + 1] = (positions, np.asarray(belief.probabilities))
        # The figure's episode: the typical one (the median error after the last grasp).
        typical = int(np.argsort(error[:, -1])[(count - 1) // 2])
        examples[name] = {"points": np.asarray(tactile_map.points_object)[np.asarray(tactile_map.valid)],
                          "true": np.asarray(episodes.T_object_sensor.translation()[typical, 0, 0]),
                          "after": {k: {"positions": positions, "probabilities": probabilities,
                                        "error_mm": error[typical, k - 1], "within": within[typical, k - 1]}
                                    for k, (positions, probabilities) in snapshots[typical].items()}}
        payload[name] = {"episodes": count, "grasps": list(range(1, args.grasps + 1)),
                         "median_error_mm": np.median(error, axis=0).tolist(),
                         "within_2mm": np.mean(error <= 2.0, axis=0).tolist(),
                         "mean_probability_within_2mm": np.mean(within, axis=0).tolist()}
        curves[name] = {"grasps": payload[name]["grasps"], "observed": payload[name]["within_2mm"],
                        "predicted": payload[name]["mean_probability_within_2mm"]}
        for k in shown:
            rows.append([name, k, 2 * k, count, float(np.median(error[:, k - 1])),
                         f"{100 * np.mean(error[:, k - 1] <= 2.0):.0f} %", float(np.mean(within[:, k - 1]))])
    print("error: RMSE of the fused touches' contact clouds at the belief's best pose, mm (up to symmetry)")
    print(format_table(["object", "grasps", "touches", "episodes", "median error (mm)", "within 2 mm",
                        "mean P(within 2 mm)"], rows))
    examples = {n: example for n, example in examples.items() if len(example["after"]) == len(shown)}
    figure = save_png(belief_figure(examples, curves), out / "demo_belief.png")
    print(f"figure: {figure}")
    return {"objects": payload, "figure": str(figure)}


def _active(args, spec, model, encoder, maps, out: Path) -> dict:
    """Beyond the paper: one active episode on the simulated cell (robot, cameras, pose feed)."""
    from tactojax.cli._active_cell import run_simulated_active
    from tactojax.io import stored_surface
    from tactojax.objects import get_object

    if args.active_grasps < 1:
        print("\n6/6 active touch: skipped (--active-grasps 0)")
        return {}
    chosen = next((m for m in maps if m.object_id == args.active_object), maps[0])
    print(f"\n6/6 active touch on the simulated robot cell: {chosen.object_id}, both fingers; after a first grasp the "
          f"live localizer chooses each grasp among {args.active_candidates} proposals by expected gain in P(within "
          f"2 mm), until P >= 0.95 or {args.active_grasps} grasps (the default scales)")
    return run_simulated_active(spec, get_object(chosen.object_id), [chosen], model, encoder,
                                surfaces=[stored_surface(out / "maps" / f"{chosen.object_id}.npz")], max_grasps=args.active_grasps, candidates=args.active_candidates, seed=args.seed,
                                figure=out / "demo_active.png")


@jax.jit
def _score_belief(symmetry, belief, episode, g):
    """After grasp ``g`` of an episode: the error over the fused touches (the paper's RMSE, up to
    the object's symmetry: ``(symmetries, axis, centre)`` of its map), the belief's P(within 2 mm)
    and its hypotheses' first-sensor positions."""
    import jax.numpy as jnp

    from tactojax.localize._new_grasps import _errors

    grasps, fingers = episode.openings.shape[0], 2
    T_true = jax.tree.map(lambda x: x[:, :fingers].reshape(-1, *x.shape[2:]), episode.T_object_sensor)
    fused = (jnp.arange(grasps)[:, None] <= g).repeat(fingers, axis=1).reshape(-1)
    _, symmetric, _, _ = _errors(T_true, belief.sensor_pose(T_true), episode.cloud_mean[:, :fingers].reshape(-1, 3),
                                 episode.cloud_covariance[:, :fingers].reshape(-1, 3, 3), fused, *symmetry)
    return symmetric, belief.probability_within(2.0), belief.T_object_reference.translation()
