"""``tactojax eval-localization MAP...``: leave-one-out localization on object maps (Table III)."""

from __future__ import annotations

from tactojax.cli._maps import (add_encoder_argument, histogram_panel, is_symmetric, load_maps_with_features,
                               object_symmetries)
from tactojax.cli._table import format_table, write_json

DEFAULT_METHODS = "random,cti,cti-icp-1,cti-icp-5"
DEFAULT_TEST_METHODS = "cti-icp-5,belief"
DEFAULT_MODEL = "bundled:fast-gelslim-0.5"


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "eval-localization", help="leave-one-out localization on tactile maps (Table III)",
        description="Every imprint of each map is localized against the rest of its map with each "
                    "method; prints the median RMSE (mm) between the imprint's cloud at its true and "
                    "estimated pose (paper section VI), a symmetry-aware RMSE for symmetric catalog "
                    "objects, and saves the error histograms.")
    parser.add_argument("maps", nargs="+", help="tactile maps (.npz) from `tactojax map`")
    parser.add_argument("--methods", default=None,
                        help="comma-separated: belief, random, cti, cti-icp-N, cti-icp-multistart-N, cti-search-N "
                             f"(default {DEFAULT_METHODS}; with --test {DEFAULT_TEST_METHODS})")
    add_encoder_argument(parser)
    parser.add_argument("--queries", type=int, default=None, help="at most this many held-out touches per map")
    parser.add_argument("--map-sizes", action="store_true",
                        help="also the map-size study (paper Fig. 7: 10/25/50/75/100 %% of the touches)")
    parser.add_argument("--figure", metavar="PNG", default="localization.png", help="histogram figure")
    parser.add_argument("--json", metavar="PATH", help="write the metrics as JSON")
    parser.add_argument("--seed", type=int, default=0)
    new = parser.add_argument_group("new grasps (instead of leave-one-out)")
    new.add_argument("--test", metavar="DIR",
                     help="a new-grasps test set (`tactojax simulate OBJECT --protocol grasps`): every grasp "
                          "localized alone with each method, and the belief fused over the grasps of each episode")
    new.add_argument("--touches", type=int, default=None,
                     help="fuse the first k = 1..K grasps of each episode (default: all of them)")
    new.add_argument("--fingers", type=int, choices=[1, 2], default=1,
                     help="fingers fused per grasp (2 needs a test set simulated with --fingers 2)")
    new.add_argument("--model", default=DEFAULT_MODEL, help=f"shape model for the test images (default {DEFAULT_MODEL})")
    parser.set_defaults(run=run)


def run(args) -> int:
    if args.test:
        from tactojax.cli._eval_new_grasps import run_new_grasps

        return run_new_grasps(args)
    import jax
    import numpy as np

    from tactojax.localize import evaluate_localization, map_size_study, parse_method
    from tactojax.viz import localization_histogram_figure, map_size_figure, save_png

    methods = [parse_method(m).name for m in (args.methods or DEFAULT_METHODS).split(",") if m.strip()]
    if "belief" in methods:
        raise ValueError("leave-one-out with the belief is not supported yet: use --test DIR (new grasps)")
    maps, _ = load_maps_with_features(args.maps, args.encoder)
    key = jax.random.key(args.seed)
    rows, payload, histograms, sizes = [], {"methods": methods, "objects": {}}, {}, {}
    for tactile_map in maps:
        symmetries = object_symmetries(tactile_map.object_id)
        valid = np.flatnonzero(np.asarray(tactile_map.imprint_valid))
        if args.queries is not None and args.queries < len(valid):
            valid = np.sort(np.random.default_rng(args.seed).choice(valid, args.queries, replace=False))
        results = evaluate_localization(key, tactile_map, methods, symmetries=symmetries, queries=valid,
                                        progress=True)
        summaries = {name: r.summary() for name, r in results.items()}
        symmetric = is_symmetric(symmetries)
        for name, s in summaries.items():
            rows.append([tactile_map.object_id, name, s["rmse_mm"]["median"],
                         s["symmetric_rmse_mm"]["median"] if symmetric else "-",
                         s["translation_mm"]["median"], s["rotation_deg"]["median"],
                         f"{100 * s['within_mm']['2']:.0f} %"])
        title, panel = histogram_panel(tactile_map.object_id, results, symmetries)
        histograms[title] = panel
        payload["objects"][tactile_map.object_id] = {"imprints": len(tactile_map), "queries": int(len(valid)),
                                                     "symmetric": symmetric, "methods": summaries}
        if args.map_sizes:
            study = map_size_study(key, tactile_map, methods=[m for m in methods if m != "random"],
                                   symmetries=symmetries)
            sizes[tactile_map.object_id] = {f: {m: float(np.median(e.rmse)) for m, e in per.items()}
                                            for f, per in study.items()}
            payload["objects"][tactile_map.object_id]["map_size"] = {str(f): v for f, v in sizes[tactile_map.object_id].items()}
    print(format_table(["object", "method", "median RMSE (mm)", "symmetric (mm)", "translation (mm)",
                        "rotation (deg)", "RMSE <= 2 mm"], rows))
    if sizes:
        size_rows = [[name, method, *(per[f][method] for f in sorted(per))]
                     for name, per in sizes.items() for method in next(iter(per.values()))]
        fractions = sorted(next(iter(sizes.values())))
        print("\nmap-size study: median RMSE (mm) against the share of touches in the map")
        print(format_table(["object", "method", *(f"{100 * f:.0f} %" for f in fractions)], size_rows))
        save_png(map_size_figure(sizes), _sibling(args.figure, "_map_size"))
    save_png(localization_histogram_figure(histograms), args.figure)
    print(f"figure: {args.figure}")
    if args.json:
        write_json(args.json, payload)
    return 0


def _sibling(path: str, suffix: str) -> str:
    from pathlib import Path

    path = Path(path)
    return str(path.with_name(path.stem + suffix + path.suffix))
