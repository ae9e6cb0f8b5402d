"""``tactojax eval-localization MAP...``: leave-one-out localization on object maps (Table III)."""

from __future__ import annotations

from tactojax.cli._maps import (add_encoder_argument, histogram_panel, is_symmetric, load_maps_with_features,
                               stored_calibration)
from tactojax.cli._table import format_table, write_json

DEFAULT_METHODS = "belief,random,cti,cti-icp-1,cti-icp-5"
DEFAULT_TEST_METHODS = "cti-icp-5,belief"
DEFAULT_MODEL = "bundled:fast-gelslim-0.5"


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "eval-localization", help="leave-one-out localization on tactile maps (Table III)",
        description="Every imprint of each map is localized against the rest of its map with the pose "
                    "belief (with each map's stored calibration; its queries are held out of the map's "
                    "surface too, in 10 folds) and the paper's baselines; prints the median RMSE (mm) "
                    "between the imprint's cloud at its true and estimated pose (paper section VI), a "
                    "symmetry-aware RMSE for symmetric catalog objects, the share within 2 mm and, for the "
                    "belief, its mean predicted P(within 2 mm) and calibration gap; saves the error "
                    "histograms.")
    parser.add_argument("maps", nargs="+", help="tactile maps (.npz) from `tactojax map`, or map catalogs")
    parser.add_argument("--methods", default=None,
                        help="comma-separated: belief, and the paper's baselines random, cti, cti-icp-N "
                             f"(default {DEFAULT_METHODS}; with --test {DEFAULT_TEST_METHODS})")
    add_encoder_argument(parser)
    parser.add_argument("--queries", type=int, default=None, help="at most this many held-out touches per map")
    parser.add_argument("--map-sizes", action="store_true",
                        help="also the map-size study (paper Fig. 7: 10/25/50/75/100 %% of the touches; the "
                             "baselines but random)")
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
    from tactojax.io import expand_catalogs

    args.maps = expand_catalogs(args.maps)
    if args.test:
        from tactojax.cli._eval_new_grasps import run_new_grasps

        return run_new_grasps(args)
    import jax
    import numpy as np

    from tactojax.localize.evaluation import calibration, calibration_gap, evaluate_localization, map_size_study
    from tactojax.localize._baselines import parse_method
    from tactojax.viz import localization_histogram_figure, map_size_figure, save_png

    methods = [parse_method(m).name for m in (args.methods or DEFAULT_METHODS).split(",") if m.strip()]
    maps, _ = load_maps_with_features(args.maps, args.encoder)
    key = jax.random.key(args.seed)
    rows, payload, histograms, sizes = [], {"methods": methods, "objects": {}}, {}, {}
    for path, tactile_map in zip(args.maps, maps):
        fit = stored_calibration(path, args.encoder) if "belief" in methods else None
        valid = np.flatnonzero(np.asarray(tactile_map.imprint_valid))
        if args.queries is not None and args.queries < len(valid):
            valid = np.sort(np.random.default_rng(args.seed).choice(valid, args.queries, replace=False))
        results = evaluate_localization(key, tactile_map, methods, calibration=fit,
                                        queries=valid, progress=True)
        symmetric = is_symmetric(tactile_map)
        summaries = {}
        for name, r in results.items():
            s = summaries[name] = r.summary()
            # P(within 2 mm) is up to the object's symmetry: compared with the symmetry-aware error.
            within = r.symmetric_rmse <= 2.0
            s["symmetric_within_2mm"] = float(np.mean(within))
            if np.all(np.isfinite(r.probability)):
                s["mean_probability_within_2mm"] = float(np.mean(r.probability))
                s["calibration"] = calibration(r.probability, within)
                s["calibrated"] = fit is not None
            rows.append([tactile_map.object_id, name, s["rmse_mm"]["median"],
                         s["symmetric_rmse_mm"]["median"] if symmetric else "-",
                         s["translation_mm"]["median"], s["rotation_deg"]["median"],
                         f"{100 * s['within_mm']['2']:.0f} %",
                         f"{100 * s['symmetric_within_2mm']:.0f} %" if symmetric else "-",
                         s.get("mean_probability_within_2mm", "-"),
                         calibration_gap(s["calibration"]) if "calibration" in s else "-"])
        title, panel = histogram_panel(tactile_map, results)
        histograms[title] = panel
        payload["objects"][tactile_map.object_id] = {"imprints": len(tactile_map), "queries": int(len(valid)),
                                                     "symmetric": symmetric, "calibrated": fit is not None,
                                                     "methods": summaries}
        study_methods = [m for m in methods if m not in ("random", "belief")]
        if args.map_sizes and study_methods:
            study = map_size_study(key, tactile_map, methods=study_methods)
            sizes[tactile_map.object_id] = {f: {m: float(np.median(e.rmse)) for m, e in per.items()}
                                            for f, per in study.items()}
            payload["objects"][tactile_map.object_id]["map_size"] = {str(f): v for f, v in sizes[tactile_map.object_id].items()}
    print(format_table(["object", "method", "median RMSE (mm)", "symmetric (mm)", "translation (mm)",
                        "rotation (deg)", "within 2 mm", "symmetric within 2 mm", "mean P(within 2 mm)",
                        "calibration gap, bins >= 10"], rows))
    if "belief" in methods:
        print("P(within 2 mm) is the belief's, up to the object's symmetry; calibration gap: the largest |predicted - "
              "observed| over its reliability bins of >= 10 beliefs (observed: the symmetry-aware error within 2 mm), "
              "and in brackets the chance that a calibrated belief shows a gap as large")
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
