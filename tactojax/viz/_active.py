"""Active-touch figure: the grasps an episode chose on the map, and the belief shrinking."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure


def active_episode_figure(points: np.ndarray, grasps: list[dict], *, title: str = "", max_points: int = 6000,
                          seed: int = 0) -> Figure:
    """One active episode: a panel per executed grasp, then the belief's P(within 2 mm) and error.

    Each panel looks down the object's z axis (the grippers approach from above): the map's
    points (grey), every grasp executed so far as a bar along its closing axis at its centre
    (numbered; dashed: it missed or taught nothing; the latest in colour), the belief's
    hypotheses of the first touch's sensor position after this grasp (dots, area and colour by
    probability) and its true position (red cross).

    Args:
        points: (P, 3) the map's points, object frame, mm.
        grasps: per executed grasp, in order: ``{"label": str, "centre": (3,), "closing": (3,)
            unit closing axis, "width_mm": float (bar length), "fused": bool, "positions": (M, 3)
            or None (no belief yet), "probabilities": (M,), "true": (3,), "within": float,
            "error_mm": float}``, all in the object frame (mm).
        title: the figure's title.
        max_points: map points drawn per panel at most (a random subset).
        seed: seed of that subset.

    Returns:
        the matplotlib figure.
    """
    points = np.asarray(points, float)
    if len(points) > max_points:
        points = points[np.random.default_rng(seed).choice(len(points), max_points, replace=False)]
    count = len(grasps)
    figure = Figure(figsize=(3.3 * count + 3.8, 3.9))
    axes = figure.subplots(1, count + 1, gridspec_kw={"width_ratios": [1.0] * count + [1.05]})
    shown = None
    for index, (axis, grasp) in enumerate(zip(axes[:-1], grasps)):
        axis.scatter(points[:, 0], points[:, 1], s=0.4, color="0.75", linewidths=0)
        for earlier, previous in enumerate(grasps[: index + 1]):
            centre, half = np.asarray(previous["centre"], float), 0.5 * previous["width_mm"]
            ends = centre[None, :2] + np.array([-half, half])[:, None] * np.asarray(previous["closing"], float)[None, :2]
            latest = earlier == index
            axis.plot(ends[:, 0], ends[:, 1], color="tab:blue" if latest else "0.35", linewidth=2.2 if latest else 1.2,
                      linestyle="-" if previous["fused"] else "--", zorder=2)
            axis.annotate(str(earlier + 1), centre[:2], fontsize=7, xytext=(3, 3), textcoords="offset points",
                          color="tab:blue" if latest else "0.35")
        if grasp["positions"] is not None:
            positions, probabilities = np.asarray(grasp["positions"], float), np.asarray(grasp["probabilities"], float)
            order = np.argsort(probabilities)
            keep = order[probabilities[order] > 1e-3]
            shown = axis.scatter(positions[keep, 0], positions[keep, 1], c=probabilities[keep],
                                 s=8 + 160 * probabilities[keep], cmap="plasma", vmin=0, vmax=1,
                                 edgecolors="black", linewidths=0.3, zorder=3)
            true = np.asarray(grasp["true"], float)
            axis.scatter([true[0]], [true[1]], marker="x", s=60, color="red", linewidths=1.8, zorder=4)
            result = f"P(within 2 mm) {grasp['within']:.2f}, error {grasp['error_mm']:.1f} mm"
        else:
            result = "no belief yet"
        axis.set_aspect("equal", adjustable="datalim")
        axis.tick_params(labelsize=6)
        axis.set_xlabel("x (mm)", fontsize=7)
        axis.set_ylabel("y (mm)", fontsize=7)
        axis.set_title(f"grasp {index + 1} ({grasp['label']})\n{result}", fontsize=8)
    if shown is not None:
        figure.colorbar(shown, ax=axes[count - 1], fraction=0.05, pad=0.02, label="hypothesis probability")
    axis = axes[-1]
    steps = [k + 1 for k, grasp in enumerate(grasps) if grasp["positions"] is not None]
    within = [grasp["within"] for grasp in grasps if grasp["positions"] is not None]
    error = [grasp["error_mm"] for grasp in grasps if grasp["positions"] is not None]
    axis.plot(steps, within, marker="o", color="tab:purple", label="P(within 2 mm)")
    axis.set_ylim(-0.03, 1.03)
    axis.set_xticks(range(1, count + 1))
    axis.set_xlabel("grasps executed")
    axis.set_ylabel("P(within 2 mm)", color="tab:purple")
    twin = axis.twinx()
    twin.plot(steps, error, marker="s", linestyle="--", color="tab:green", label="error")
    twin.axhline(2.0, color="grey", linestyle=":", linewidth=1)
    twin.set_yscale("log")
    twin.set_ylabel("error, mm (dotted: 2 mm)", color="tab:green")
    axis.set_title("the belief after each grasp", fontsize=9)
    figure.suptitle(title or "active touch: the chosen grasps (bars) and the belief's hypotheses (dots)", fontsize=10)
    return figure
