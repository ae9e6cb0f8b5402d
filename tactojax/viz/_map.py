"""Figure of a tactile map: the stitched contact cloud (the paper's "Tactile shape", Table II)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def tactile_map_figure(
    points: np.ndarray,
    path: str | Path,
    *,
    title: str = "",
    examples: tuple[np.ndarray, np.ndarray] | None = None,
    mm_per_px: float = 1.0,
    max_points: int = 30000,
    seed: int = 0,
) -> Path:
    """Save the stitched map cloud from two viewpoints, and optionally example imprints.

    The left panel is an oblique 3-D view; the right one looks along the cloud's thinnest axis
    (for a mounted catalog object the gripper's closing axis y), drawn in 2-D at true scale with
    that axis as colour, so a thin object (scissors) is not squashed into a sliver.

    Args:
        points: (N, 3) map points, object frame, mm.
        path: PNG to write (atomically).
        title: figure title (e.g. the object and the number of imprints).
        examples: optional (images (E, H, W, 3), heightmaps (E, H, W) mm) shown beside the cloud.
        mm_per_px: pixel pitch of the examples.
        max_points: points drawn at most (a random subset).
        seed: seed of that subset.
    """
    from tactojax.viz._save import save_png

    points = np.asarray(points)
    if len(points) == 0:
        raise ValueError("the map has no contact points to show")
    if len(points) > max_points:
        points = points[np.random.default_rng(seed).choice(len(points), max_points, replace=False)]
    return save_png(_map_figure(points, title=title, examples=examples, mm_per_px=mm_per_px), path, dpi=100)


def _map_figure(points: np.ndarray, *, title: str, examples, mm_per_px: float):
    """The matplotlib Figure that :func:`tactile_map_figure` saves."""
    from matplotlib.figure import Figure  # no pyplot: leaves a notebook's backend alone

    count = 0 if examples is None else len(examples[0])
    columns = 2 * max(count, 1)
    figure = Figure(figsize=(max(12, 2.4 * columns), 9 if count else 6))
    grid = figure.add_gridspec(2 if count else 1, columns, height_ratios=[2.4, 1] if count else [1])
    half = columns // 2
    _oblique_panel(figure.add_subplot(grid[0, :half], projection="3d"), points)
    _projection_panel(figure, figure.add_subplot(grid[0, half:]), points)
    for index in range(count):
        image, heightmap = examples[0][index], examples[1][index]
        height, width = heightmap.shape
        extent = (0, width * mm_per_px, height * mm_per_px, 0)
        ax = figure.add_subplot(grid[1, 2 * index])
        ax.imshow(image, extent=extent)
        ax.set_title(f"imprint {index + 1}", fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
        ax = figure.add_subplot(grid[1, 2 * index + 1])
        shown = ax.imshow(heightmap, extent=extent, cmap="viridis")
        figure.colorbar(shown, ax=ax, fraction=0.046, pad=0.02, label="predicted (mm)")
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        figure.suptitle(title, fontsize=11)
    return figure


def _oblique_panel(ax, points: np.ndarray) -> None:
    """3-D scatter at true proportions; an axis too thin for tick labels names its range instead."""
    from matplotlib.ticker import MaxNLocator

    extents = np.ptp(points, axis=0) + 1e-3
    ax.scatter(points[:, 0], points[:, 1], points[:, 2], s=0.3, c=points[:, 2], cmap="viridis", linewidths=0)
    ax.view_init(elev=25, azim=-60)
    ax.set_box_aspect(extents, zoom=0.9)  # room for the z label beside the next panel
    for index, (name, extent) in enumerate(zip("xyz", extents)):
        axis = (ax.xaxis, ax.yaxis, ax.zaxis)[index]
        label = f"{name} (mm)"
        if extent < 0.25 * extents.max():
            axis.set_ticks([])
            label = f"{name}: {points[:, index].min():.0f} to {points[:, index].max():.0f} mm"
        else:
            axis.set_major_locator(MaxNLocator(nbins=max(2, int(6 * extent / extents.max()))))
        getattr(ax, f"set_{name}label")(label, fontsize=7)
    ax.tick_params(labelsize=6)
    ax.set_title("oblique", fontsize=9)


def _projection_panel(figure, ax, points: np.ndarray) -> None:
    """The cloud seen along its thinnest axis, at equal scale, coloured by the depth along it."""
    depth = int(np.argmin(np.ptp(points, axis=0)))
    across, up = (axis for axis in range(3) if axis != depth)
    names = "xyz"
    toward_viewer = np.linalg.det(np.eye(3)[[across, up, depth]])  # +1: the depth axis points at us
    order = np.argsort(toward_viewer * points[:, depth])  # nearer points drawn last, on top
    shown = ax.scatter(points[order, across], points[order, up], c=points[order, depth], s=0.3, cmap="viridis",
                       linewidths=0)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"{names[across]} (mm)", fontsize=7)
    ax.set_ylabel(f"{names[up]} (mm)", fontsize=7)
    ax.tick_params(labelsize=6)
    side = "+" if toward_viewer > 0 else "-"
    ax.set_title(f"seen from {side}{names[depth]}, along the thinnest axis (true scale)", fontsize=9)
    figure.colorbar(shown, ax=ax, fraction=0.046, pad=0.02, label=f"{names[depth]} (mm)")
