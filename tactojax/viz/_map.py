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

    Args:
        points: (N, 3) map points, object frame, mm.
        path: PNG to write (atomically).
        title: figure title (e.g. the object and the number of imprints).
        examples: optional (images (E, H, W, 3), heightmaps (E, H, W) mm) shown beside the cloud.
        mm_per_px: pixel pitch of the examples.
        max_points: points drawn at most (a random subset).
        seed: seed of that subset.
    """
    from matplotlib.figure import Figure  # no pyplot: leaves a notebook's backend alone

    from tactojax.viz._save import save_png

    points = np.asarray(points)
    if len(points) == 0:
        raise ValueError("the map has no contact points to show")
    if len(points) > max_points:
        points = points[np.random.default_rng(seed).choice(len(points), max_points, replace=False)]
    count = 0 if examples is None else len(examples[0])
    columns = 2 * max(count, 1)
    figure = Figure(figsize=(max(12, 2.4 * columns), 9 if count else 6))
    grid = figure.add_gridspec(2 if count else 1, columns, height_ratios=[2.4, 1] if count else [1])
    half = columns // 2
    aspect = np.ptp(points, axis=0) + 1e-3
    for column, (elevation, azimuth, label) in enumerate([(25, -60, "oblique"), (90, -90, "from above")]):
        ax = figure.add_subplot(grid[0, column * half:(column + 1) * half], projection="3d")
        ax.scatter(points[:, 0], points[:, 1], points[:, 2], s=0.3, c=points[:, 2], cmap="viridis",
                   linewidths=0)
        ax.view_init(elev=elevation, azim=azimuth)
        ax.set_box_aspect(aspect)
        ax.set_title(label, fontsize=9)
        for axis, name in zip("xyz", ("x", "y", "z")):
            getattr(ax, f"set_{axis}label")(f"{name} (mm)", fontsize=7)
        ax.tick_params(labelsize=6)
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
    return save_png(figure, path, dpi=100)
