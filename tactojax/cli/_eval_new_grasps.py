"""``tactojax eval-localization MAP... --test DIR``: localization of new grasps, single and fused."""

from __future__ import annotations

from tactojax.cli._maps import is_symmetric, maps_and_query_encoder, stored_calibration
from tactojax.cli._table import format_table, share_with_interval, write_json


def run_new_grasps(args) -> int:
    import numpy as np

    from tactojax.cli._eval_localization import DEFAULT_TEST_METHODS
    from tactojax.io import resolve_shape_model, stored_surface
    from tactojax.localize import LocalizationMap
    from tactojax.localize.evaluation import calibration, calibration_gap, evaluate_new_grasps, load_test_episodes
    from tactojax.localize._baselines import parse_method
    from tactojax.viz import new_grasps_figure, save_png

    methods = [parse_method(m).name for m in (args.methods or DEFAULT_TEST_METHODS).split(",") if m.strip()]
    maps, encoder = maps_and_query_encoder(args.maps, args.encoder)
    model = resolve_shape_model(args.model)
    rows, payload, curves, calibrations = [], {"methods": methods, "test": args.test, "objects": {}}, {}, {}
    for path, tactile_map in zip(args.maps, maps):
        episodes, recorded_fingers = load_test_episodes(args.test, tactile_map.object_id, model, encoder)
        if args.fingers > recorded_fingers:
            raise ValueError(f"--fingers {args.fingers}: the test set records {recorded_fingers} finger per grasp "
                             "(simulate it with --fingers 2)")
        if args.touches is not None:
            if not 1 <= args.touches <= episodes.openings.shape[1]:
                raise ValueError(f"--touches must be in 1..{episodes.openings.shape[1]} (grasps per episode)")
            import jax

            episodes = jax.tree.map(lambda x: x[:, :args.touches], episodes)
        symmetric = is_symmetric(tactile_map)
        fit = stored_calibration(path, args.encoder) if "belief" in methods else None
        view = LocalizationMap.from_tactile_map(tactile_map, calibration=fit, surface=stored_surface(path))
        results = evaluate_new_grasps(view, episodes, methods, fingers=args.fingers, progress=True)
        summaries = [r.summary(symmetric=symmetric) for r in results]
        for r, s in zip(results, summaries):
            rows.append([tactile_map.object_id, r.method, r.fingers, r.grasps if r.fused else "1 (each)", s["count"], s["median_rmse_mm"],
                         s["median_symmetric_rmse_mm"] if symmetric else "-",
                         f"{100 * s['within_mm']['1']:.0f} %", share_with_interval(s),
                         f"{100 * s['within_mm']['5']:.0f} %",
                         s["median_translation_mm"], s["median_rotation_deg"],
                         calibration_gap(s["calibration"]) if "calibration" in s else "-",
                         s.get("mean_nll_truth", "-"),
                         f"{100 * s['coverage_90']:.0f} %" if "coverage_90" in s else "-"])
        fused = [(r, s) for r, s in zip(results, summaries) if r.fused]
        key = "median_symmetric_rmse_mm" if symmetric else "median_rmse_mm"
        curves[f"{tactile_map.object_id}, {args.fingers} finger{'s' * (args.fingers > 1)}"] = {
            "grasps": [r.grasps for r, _ in fused], "median_mm": [_plotted(s[key]) for _, s in fused],
            "single": {r.method: _plotted(s[key]) for r, s in zip(results, summaries) if not r.fused}}
        beliefs = [r for r in results if r.method == "belief"]
        if beliefs:
            error = np.concatenate([r.symmetric_rmse if symmetric else r.rmse for r in beliefs])
            calibrations[tactile_map.object_id] = calibration(np.concatenate([r.probability for r in beliefs]),
                                                              error <= 2.0)
        payload["objects"][tactile_map.object_id] = {
            "imprints": len(tactile_map), "episodes": int(episodes.openings.shape[0]), "symmetric": symmetric,
            "calibrated": fit is not None,
            "results": summaries, "calibration": calibrations.get(tactile_map.object_id)}
    print(format_table(["object", "method", "fingers", "grasps", "count", "median RMSE (mm)", "symmetric (mm)",
                        "<= 1 mm", "<= 2 mm [95 % interval]", "<= 5 mm", "translation (mm)", "rotation (deg)",
                        "calibration gap, bins >= 10", "NLL of truth", "90 % set holds truth"], rows))
    if calibrations:
        print("\nbelief calibration: predicted P(error <= 2 mm) against the observed share, per bin")
        cal_rows = [[name, f"{b['bin'][0]:.1f}-{b['bin'][1]:.1f}", b["count"],
                     "-" if b["predicted"] is None else b["predicted"], "-" if b["observed"] is None else b["observed"]]
                    for name, table in calibrations.items() for b in table["bins"]]
        print(format_table(["object", "bin", "count", "predicted", "observed"], cal_rows))
        chance_rows = [[name, table["max_gap_binned"], table["calibrated_max_gap_95"], table["calibrated_p"]]
                       for name, table in calibrations.items() if table["max_gap_binned"] is not None]
        if chance_rows:
            print("\nlargest gap over the bins of >= 10 beliefs, against what a calibrated belief shows by chance")
            print(format_table(["object", "gap", "calibrated: 95 % of gaps below", "P(gap this large | calibrated)"],
                               chance_rows))
    save_png(new_grasps_figure(curves, calibrations), args.figure)
    print(f"figure: {args.figure}")
    if args.json:
        write_json(args.json, payload)
    return 0


def _plotted(median: float | None) -> float:
    """A median for the figure: NaN (not drawn) where there is none (most localizations without
    an estimate)."""
    return float("nan") if median is None else median
