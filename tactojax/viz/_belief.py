"""New-grasps figures: error against the number of fused grasps, and belief calibration."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure


def new_grasps_figure(curves: dict[str, dict], calibrations: dict[str, dict]) -> Figure:
    """Two panels: median error against fused grasps, and the reliability diagram.

    Args:
        curves: ``{label (object, fingers): {"grasps": [1..K], "median_mm": [...], "single": {method: median}}}``.
        calibrations: ``{object: calibration dict}`` with ``bins`` of ``predicted``/``observed``/``count``
            (:func:`tactojax.localize.calibration`).

    Returns:
        the matplotlib figure.
    """
    figure = Figure(figsize=(10.0, 3.8))
    curve_axis, reliability_axis = figure.subplots(1, 2)
    for index, (label, curve) in enumerate(curves.items()):
        line, = curve_axis.plot(curve["grasps"], curve["median_mm"], marker="o", label=f"{label}: belief")
        for method, median in curve.get("single", {}).items():
            curve_axis.scatter([1], [median], marker="x", color=line.get_color(), zorder=3)
            if index == 0:
                curve_axis.annotate(method, (1, median), fontsize=7, xytext=(4, 0), textcoords="offset points")
    curve_axis.set_xticks(sorted({g for curve in curves.values() for g in curve["grasps"]} | {1}))
    curve_axis.axhline(2.0, color="grey", linestyle=":", linewidth=1)
    curve_axis.set_xlabel("grasps fused")
    curve_axis.set_ylabel("median RMSE, mm (x: single-touch baselines)")
    curve_axis.set_yscale("log")
    curve_axis.legend(fontsize=7)
    curve_axis.set_title("error against touches")
    reliability_axis.plot([0, 1], [0, 1], color="grey", linestyle=":", linewidth=1)
    for name, table in calibrations.items():
        rows = [r for r in table["bins"] if r["count"]]
        reliability_axis.plot([r["predicted"] for r in rows], [r["observed"] for r in rows], marker="o",
                              label=f"{name} (max gap {table['max_gap']:.2f})")
    reliability_axis.set_xlim(0, 1)
    reliability_axis.set_ylim(0, 1)
    reliability_axis.set_xlabel("predicted P(error <= 2 mm)")
    reliability_axis.set_ylabel("observed share")
    reliability_axis.set_title("belief calibration")
    reliability_axis.legend(fontsize=7)
    figure.tight_layout()
    return figure
