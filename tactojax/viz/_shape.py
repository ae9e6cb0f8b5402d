"""Figure of local-shape predictions: image | true heightmap | predicted | error."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def shape_examples_figure(
    images: np.ndarray,
    true_heightmaps: np.ndarray,
    predicted_heightmaps: np.ndarray,
    path: str | Path,
    *,
    titles: list[str] | None = None,
    mm_per_px: float = 1.0,
) -> Path:
    """One row per example: tactile image, true and predicted heightmaps (mm), and their error.

    Args:
        images: (N, H, W, 3) RGB in [0, 1] or uint8.
        true_heightmaps, predicted_heightmaps: (N, H, W) mm.
        path: PNG to write (atomically).
        titles: optional label per row (e.g. the object).
        mm_per_px: pixel pitch, for axes in mm.
    """
    from matplotlib.figure import Figure  # no pyplot: leaves a notebook's backend alone

    from tactojax.viz._save import save_png

    count = len(images)
    height, width = np.shape(images)[1:3]
    extent = (0, width * mm_per_px, height * mm_per_px, 0)
    figure = Figure(figsize=(12, 2.6 * count))
    axes = figure.subplots(count, 4, squeeze=False)
    for row in range(count):
        error = predicted_heightmaps[row] - true_heightmaps[row]
        top = max(float(true_heightmaps[row].max()), 1e-3)
        limit = max(float(np.abs(error).max()), 1e-3)
        panels = [
            (images[row], None, "tactile image"),
            (true_heightmaps[row], dict(cmap="viridis", vmin=0, vmax=top), "true heightmap (mm)"),
            (predicted_heightmaps[row], dict(cmap="viridis", vmin=0, vmax=top), "predicted (mm)"),
            (error, dict(cmap="RdBu_r", vmin=-limit, vmax=limit),
             f"error (mm), RMSE {np.sqrt(np.mean(error**2)):.3f}"),
        ]
        for ax, (array, style, label) in zip(axes[row], panels):
            shown = ax.imshow(array, extent=extent, **(style or {}))
            if style is not None:
                figure.colorbar(shown, ax=ax, fraction=0.046, pad=0.02)
            ax.set_title(label if titles is None or ax is not axes[row][0] else f"{titles[row]}",
                         fontsize=9)
            ax.set_xticks([])
            ax.set_yticks([])
    return save_png(figure, path, dpi=90)
