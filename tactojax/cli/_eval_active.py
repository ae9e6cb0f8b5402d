"""``tactojax eval-active MAP... --object OBJECT``: active touch against random grasps, in closed loop."""

from __future__ import annotations

from tactojax.cli._maps import add_encoder_argument, is_symmetric
from tactojax.cli._table import format_table, share_with_interval, write_json

DEFAULT_POLICIES = "active,random,largest-contact"


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "eval-active", help="closed-loop active touch in simulation: chosen grasps against random ones",
        description="Each episode places the object at a random turn and makes a first random grasp; each "
                    "policy then chooses every further grasp (active: the largest expected gain in P(within "
                    "2 mm), predicted from the map; largest-contact; random: the new-grasps protocol's next "
                    "grasp), which the simulator executes at the true placement (a miss is a spent grasp). "
                    "Prints, per object, policy and k = 1..K grasps, the median RMSE, its symmetry-aware "
                    "value, the shares within 1, 2 and 5 mm and the belief's calibration; and the stopping "
                    "rule's figures.")
    parser.add_argument("maps", nargs="+", help="tactile maps (.npz), one per --object")
    parser.add_argument("--object", nargs="+", required=True,
                        help="what `tactojax simulate` takes, one per map: a catalog name, ycb:ID or a mesh path")
    parser.add_argument("--mesh-units", choices=["m", "cm", "mm"], default="m", help="length unit of a mesh file")
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--max-grasps", type=int, default=3)
    parser.add_argument("--fingers", type=int, choices=[2], default=2, help="fingers with a gel (2)")
    parser.add_argument("--policies", default=DEFAULT_POLICIES, help=f"comma-separated (default {DEFAULT_POLICIES})")
    parser.add_argument("--candidates", type=int, default=64, help="grasps proposed per choice (default 64)")
    parser.add_argument("--hypotheses", type=int, default=8, help="belief hypotheses a gain is expected over")
    parser.add_argument("--objective", choices=["within", "entropy"], default="within")
    parser.add_argument("--stop", type=float, default=0.95, help="stop when P(within 2 mm) reaches this")
    parser.add_argument("--turns-deg", type=float, nargs="+", default=[0.0, 90.0, 180.0, 270.0])
    parser.add_argument("--model", default="bundled:fast-gelslim-0.5", help="shape model for the simulated images")
    add_encoder_argument(parser)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", metavar="PATH", help="write the metrics as JSON")
    parser.add_argument("--figure", metavar="PNG", default="active.png", help="share within 2 mm against grasps")
    parser.add_argument("--no-progress", action="store_true")
    parser.set_defaults(run=run)


def run(args) -> int:
    import jax
    import numpy as np

    from tactojax.cli._maps import maps_and_query_encoder, stored_calibration
    from tactojax.features import encode_images
    from tactojax.io import resolve_shape_model, stored_surface
    from tactojax.localize import LocalizationMap
    from tactojax.localize.active import ActiveSettings
    from tactojax.localize._active_episodes import POLICIES, run_active_episodes
    from tactojax.localize._localizer import observe as observe_frame
    from tactojax.objects import resolve_object

    policies = [p.strip() for p in args.policies.split(",") if p.strip()]
    if unknown := sorted(set(policies) - set(POLICIES)):
        raise ValueError(f"unknown policies {unknown}; choose from {', '.join(POLICIES)}")
    if len(args.object) != len(args.maps):
        raise ValueError(f"give one --object per map ({len(args.maps)} maps, {len(args.object)} objects)")
    if args.episodes < 1 or args.max_grasps < 2:
        raise ValueError("need at least one episode and two grasps (the first is random)")
    maps, encoder = maps_and_query_encoder(args.maps, args.encoder)
    model = resolve_shape_model(args.model)
    observe_one = jax.jit(lambda image: observe_frame(model, image)[1:3])

    def observe(images):
        heightmaps, masks = zip(*(observe_one(image) for image in images))
        return np.stack(heightmaps), np.stack(masks), encode_images(encoder, images)

    settings = ActiveSettings(hypotheses=args.hypotheses, objective=args.objective, stop_probability=args.stop)
    rows, stop_rows, payload, curves = [], [], {"policies": policies, "seed": args.seed, "objects": {}}, {}
    for path, tactile_map, name in zip(args.maps, maps, args.object):
        obj = resolve_object(name, units=args.mesh_units)
        spec = _simulated_sensor(path, tactile_map, model)
        view = LocalizationMap.from_tactile_map(tactile_map, calibration=stored_calibration(path, args.encoder),
                                                surface=stored_surface(path))
        result = run_active_episodes(jax.random.key(args.seed), view, obj, spec, observe, episodes=args.episodes,
                                     max_grasps=args.max_grasps, policies=policies, candidates=args.candidates,
                                     turns_deg=args.turns_deg, settings=settings, progress=not args.no_progress)
        entry, object_rows, object_stop_rows, object_curves = _summarise_object(result, obj, tactile_map, policies,
                                                                                args)
        payload["objects"][tactile_map.object_id] = entry
        rows += object_rows
        stop_rows += object_stop_rows
        curves.update(object_curves)
    print(format_table(["object", "policy", "grasps", "median RMSE (mm)", "symmetric (mm)", "<= 1 mm",
                        "<= 2 mm [95 % interval]", "<= 5 mm", "mean P(within 2 mm)", "calibration gap, bins >= 10",
                        "spent"], rows))
    print(f"\nstopping rule: P(within 2 mm) >= {args.stop} within {args.max_grasps} grasps")
    print(format_table(["object", "policy", "stopped", "within 2 mm of those", "mean grasps to stop"], stop_rows))
    for name, entry in payload["objects"].items():
        timing = entry["ranking_s"]
        if timing["median_s"] is not None:
            print(f"{name}: ranking {timing['candidates']} candidates: {1000 * timing['median_s']:.0f} ms median "
                  f"({timing['calls']} calls; the first, with compilation: {timing['first_s']:.1f} s)")
    _figure(curves, args.figure)
    print(f"figure: {args.figure}")
    if args.json:
        write_json(args.json, payload)
    return 0


def _simulated_sensor(path, tactile_map, model):
    """The simulated sensor of a map's images (its preset, at the map's resolution); a ValueError
    when it or the shape model does not match the map."""
    from tactojax.sensor import SENSOR_PRESETS, sensor_preset

    sensor = tactile_map.sensor or "gelslim"
    full = sensor_preset(sensor) if sensor in SENSOR_PRESETS else sensor_preset("gelslim")
    spec = sensor_preset(full.name if sensor in SENSOR_PRESETS else "gelslim",
                         scale=tactile_map.image_shape[1] / full.width_px)
    if abs(spec.mm_per_px - tactile_map.mm_per_px) > 1e-6 or model.image_shape != tactile_map.image_shape:
        raise ValueError(f"{path}: the map's sensor ({tactile_map.image_shape} px at "
                         f"{tactile_map.mm_per_px} mm/px) does not match the simulated one or the shape model")
    return spec


def _summarise_object(result, obj, tactile_map, policies, args):
    """One object's closed-loop figures: its JSON entry, its rows of the results and stopping-rule
    tables, and its curves of the share within 2 mm against grasps (one per policy)."""
    import numpy as np

    from tactojax.localize._compare import finite_or_none
    from tactojax.localize.evaluation import calibration, calibration_gap, share_interval

    rows, stop_rows, curves = [], [], {}
    symmetric = is_symmetric(tactile_map)
    summaries, stops = [], {}
    for policy in policies:
        error = result.symmetric_rmse[policy] if symmetric else result.rmse[policy]
        for k in range(args.max_grasps):
            within = error[:, k] <= 2.0
            summary = {"policy": policy, "grasps": k + 1, "fingers": args.fingers, "count": args.episodes,
                       "median_rmse_mm": finite_or_none(np.median(result.rmse[policy][:, k])),
                       "median_symmetric_rmse_mm": finite_or_none(np.median(result.symmetric_rmse[policy][:, k])),
                       "within_mm": {str(t): float(np.mean(error[:, k] <= t)) for t in (1, 2, 5)},
                       "within_2mm_interval": share_interval(int(np.sum(within)), len(within)),
                       "spent_share": float(np.mean(result.spent[policy][:, k])),
                       "calibration": calibration(result.probability[policy][:, k], within),
                       "per_localization": {"rmse_mm": [finite_or_none(x) for x in result.rmse[policy][:, k]],
                                            "symmetric_rmse_mm": [finite_or_none(x)
                                                                  for x in result.symmetric_rmse[policy][:, k]],
                                            "p_within_2mm": result.probability[policy][:, k].tolist(),
                                            "spent": result.spent[policy][:, k].tolist()}}
            summaries.append(summary)
            rows.append([obj.name, policy, k + 1, summary["median_rmse_mm"],
                         summary["median_symmetric_rmse_mm"] if symmetric else "-",
                         f"{100 * summary['within_mm']['1']:.0f} %", share_with_interval(summary),
                         f"{100 * summary['within_mm']['5']:.0f} %",
                         float(np.mean(result.probability[policy][:, k])),
                         calibration_gap(summary["calibration"]), f"{100 * summary['spent_share']:.0f} %"])
        stops[policy] = stop = stop_figures(result.probability[policy], error, args.stop)
        stop_rows.append([obj.name, policy, f"{100 * stop['stopped_share']:.0f} %",
                          "-" if stop["within_2mm_of_stopped"] is None else f"{100 * stop['within_2mm_of_stopped']:.0f} %",
                          "-" if stop["mean_grasps_to_stop"] is None else stop["mean_grasps_to_stop"]])
        curves[f"{obj.name}: {policy}"] = [s["within_mm"]["2"] for s in summaries if s["policy"] == policy]
    hard = np.isin(np.round(result.turn_deg) % 360, (90, 270))
    ranking = np.asarray(result.ranking_s)
    entry = {
        "episodes": args.episodes, "symmetric": symmetric, "results": summaries, "stop": stops,
        "turn_deg": result.turn_deg.tolist(),
        "within_2mm_at_90_270": {p: [float(np.mean((result.symmetric_rmse[p] if symmetric else result.rmse[p])
                                                   [hard, k] <= 2.0)) if hard.any() else None
                                     for k in range(args.max_grasps)] for p in policies},
        "ranking_s": {"candidates": args.candidates, "hypotheses": args.hypotheses, "calls": int(len(ranking)),
                      "first_s": float(ranking[0]) if len(ranking) else None,
                      "median_s": float(np.median(ranking[1:])) if len(ranking) > 1 else None}}
    return entry, rows, stop_rows, curves


def stop_figures(probability, error, threshold: float) -> dict:
    """The stopping rule on (E, K) beliefs and errors: the share of episodes whose P(within 2 mm)
    reaches ``threshold`` within K grasps, the share of those within 2 mm when they stop, and
    the mean grasps to stop."""
    import numpy as np

    reached = probability >= threshold
    stopped = reached.any(axis=1)
    at = np.argmax(reached, axis=1)
    within = error[np.arange(len(error)), at] <= 2.0
    return {"threshold": threshold, "stopped_share": float(np.mean(stopped)),
            "within_2mm_of_stopped": float(np.mean(within[stopped])) if stopped.any() else None,
            "mean_grasps_to_stop": float(np.mean(at[stopped] + 1)) if stopped.any() else None}


def _figure(curves: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    from tactojax.viz import save_png

    figure, axis = plt.subplots(figsize=(5, 3.5))
    for label, shares in curves.items():
        axis.plot(range(1, len(shares) + 1), [100 * s for s in shares], marker="o", label=label)
    axis.set_xlabel("grasps")
    axis.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
    axis.set_ylabel("within 2 mm (%)")
    axis.set_ylim(0, 100)
    axis.legend(fontsize=7)
    figure.tight_layout()
    save_png(figure, path, dpi=120)  # never half-written
    plt.close(figure)
