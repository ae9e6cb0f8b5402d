"""New-grasps figures: error against the number of fused grasps, and belief calibration."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.layout_engine import PlaceHolderLayoutEngine


def new_grasps_figure(curves: dict[str, dict], calibrations: dict[str, dict]) -> Figure:
    """Two panels: median error against fused grasps, and the reliability diagram.

    Args:
        curves: ``{label (object, fingers): {"grasps": [1..K], "median_mm": [...], "single": {method: median}}}``.
        calibrations: ``{object: calibration dict}`` with ``bins`` of ``predicted``/``observed``/``count``
            (:func:`tactojax.localize.evaluation.calibration`).

    Returns:
        the matplotlib figure.
    """
    from tactojax.localize.evaluation import calibration_gap  # here: importing the figures starts no JAX

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
                              label=f"{name} (gap, bins >= 10: {calibration_gap(table)})")
    reliability_axis.set_xlim(0, 1)
    reliability_axis.set_ylim(0, 1)
    reliability_axis.set_xlabel("predicted P(error <= 2 mm)")
    reliability_axis.set_ylabel("observed share")
    reliability_axis.set_title("belief calibration")
    reliability_axis.legend(fontsize=7)
    figure.tight_layout()
    return figure


def belief_figure(examples: dict[str, dict], curves: dict[str, dict], *, max_points: int = 6000,
                  seed: int = 0) -> Figure:
    """The pose belief at work: where it puts the sensor after 1 and after K grasps of one
    example episode per object, and how often it is right against how sure it says it is.

    One column per object, two rows (after the first grasp, after the last one): the map's
    points (grey) seen along their thinnest axis, the belief's hypotheses of the first touch's
    sensor position (dots, area and colour by probability) and the true position (red cross).
    The last column: per object, the observed share of episodes within 2 mm after k grasps
    (solid) and the belief's mean predicted P(within 2 mm) (dashed).

    Args:
        examples: ``{object: {"points": (P, 3) map points, object frame, mm, "true": (3,) the
            first sensor's true position, "after": {k: {"positions": (M, 3) hypotheses' first
            sensor positions, "probabilities": (M,), "error_mm": float, "within": float}}}}``
            with the same two k for every object.
        curves: ``{object: {"grasps": [1..K], "observed": [...], "predicted": [...]}}``.
        max_points: map points drawn per panel at most (a random subset).
        seed: seed of that subset.

    Returns:
        the matplotlib figure (its grid sets its own spacing).
    """
    names = list(examples)
    steps = sorted(next(iter(examples.values()))["after"])
    figure = Figure(figsize=(3.4 * len(names) + 4.4, 6.8))
    # The grid's own spacing, not tight_layout (which cannot place a colorbar spanning the rows).
    figure.set_layout_engine(PlaceHolderLayoutEngine(adjust_compatible=True, colorbar_gridspec=True))
    grid = figure.add_gridspec(len(steps), len(names) + 2, width_ratios=[1.0] * len(names) + [0.05, 1.1],
                               wspace=0.45, hspace=0.45)
    rng = np.random.default_rng(seed)
    for column, name in enumerate(names):
        example = examples[name]
        points = np.asarray(example["points"], float)
        if len(points) > max_points:
            points = points[rng.choice(len(points), max_points, replace=False)]
        depth = int(np.argmin(np.ptp(points, axis=0)))
        across, up = (axis for axis in range(3) if axis != depth)
        for row, step in enumerate(steps):
            after = example["after"][step]
            axis = figure.add_subplot(grid[row, column])
            axis.scatter(points[:, across], points[:, up], s=0.4, color="0.75", linewidths=0)
            positions = np.asarray(after["positions"], float)
            probabilities = np.asarray(after["probabilities"], float)
            order = np.argsort(probabilities)  # the most probable on top
            keep = order[probabilities[order] > 1e-3]
            shown = axis.scatter(positions[keep, across], positions[keep, up], c=probabilities[keep],
                                 s=8 + 160 * probabilities[keep], cmap="plasma", vmin=0, vmax=1,
                                 edgecolors="black", linewidths=0.3, zorder=3)
            true = np.asarray(example["true"], float)
            axis.scatter([true[across]], [true[up]], marker="x", s=60, color="red", linewidths=1.8, zorder=4)
            axis.set_aspect("equal", adjustable="datalim")
            axis.tick_params(labelsize=6)
            axis.set_xlabel(f"{'xyz'[across]} (mm)", fontsize=7)
            axis.set_ylabel(f"{'xyz'[up]} (mm)", fontsize=7)
            axis.set_title(f"{name}, after {step} grasp{'s' * (step > 1)}\n"
                           f"P(within 2 mm) {after['within']:.2f}, error {after['error_mm']:.1f} mm", fontsize=8)
    figure.colorbar(shown, cax=figure.add_subplot(grid[:, len(names)]), label="hypothesis probability")
    figure.suptitle("the pose belief on new grasps: its hypotheses of the first sensor's position (dots; symmetric "
                    "copies are one pose) and the truth (red x)", fontsize=10)
    axis = figure.add_subplot(grid[:, -1])
    for name, curve in curves.items():
        line, = axis.plot(curve["grasps"], curve["observed"], marker="o", label=f"{name}: observed")
        axis.plot(curve["grasps"], curve["predicted"], marker="s", linestyle="--", color=line.get_color(),
                  label=f"{name}: predicted")
    axis.set_ylim(-0.03, 1.03)
    axis.set_xticks(sorted({g for curve in curves.values() for g in curve["grasps"]}))
    axis.set_xlabel("grasps fused (both fingers)")
    axis.set_ylabel("share of episodes within 2 mm")
    axis.yaxis.set_label_position("right")  # clear of the colour bar's ticks on its left
    axis.yaxis.tick_right()
    axis.set_title("within 2 mm: observed (solid)\nagainst the belief's mean P (dashed)", fontsize=9)
    axis.legend(fontsize=7)
    return figure
