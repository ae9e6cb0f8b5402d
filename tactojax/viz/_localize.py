"""Localization figures: error histograms (paper Fig. 6), map-size curves (Fig. 7), confusion."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure  # no pyplot: leaves a notebook's backend alone


def localization_histogram_figure(results: dict[str, dict], *, max_mm: float = 80.0, bin_mm: float = 5.0) -> Figure:
    """Histograms of the leave-one-out RMSE per object (one panel each), one colour per method.

    Args:
        results: ``{panel title (the object): {method: per-query RMSE array (mm)}}``.
        max_mm: right end of the histogram (the paper's 80 mm); larger errors go in the last bin.
        bin_mm: bin width, mm.

    Returns:
        the matplotlib figure.
    """
    objects = list(results)
    columns = min(3, len(objects))
    rows = int(np.ceil(len(objects) / columns))
    figure = Figure(figsize=(4.2 * columns, 3.0 * rows))
    axes = figure.subplots(rows, columns, squeeze=False)
    edges = np.arange(0.0, max_mm + bin_mm, bin_mm)
    for axis, name in zip(axes.ravel(), objects):
        for method, rmse in results[name].items():
            values = np.clip(np.asarray(rmse, float), 0.0, max_mm - 1e-6)
            weights = np.full(len(values), 100.0 / max(len(values), 1))
            axis.hist(values, bins=edges, weights=weights, histtype="step", linewidth=1.5,
                      label=f"{method} (median {np.median(rmse):.1f})")
        axis.set_title(name)
        axis.set_xlabel("RMSE, mm")
        axis.set_ylabel("% of touches")
        axis.legend(fontsize=7)
    for axis in axes.ravel()[len(objects):]:
        axis.axis("off")
    return figure


def map_size_figure(results: dict[str, dict[float, dict[str, float]]]) -> Figure:
    """Median RMSE against the fraction of touches in the map (paper Fig. 7).

    Args:
        results: ``{object: {fraction: {method: median RMSE (mm)}}}``.
    """
    objects = list(results)
    figure = Figure(figsize=(3.6 * len(objects), 3.0))
    axes = figure.subplots(1, len(objects), squeeze=False)
    for axis, name in zip(axes[0], objects):
        fractions = sorted(results[name])
        methods = list(results[name][fractions[0]])
        for method in methods:
            axis.plot([100 * f for f in fractions], [results[name][f][method] for f in fractions],
                      marker="o", label=method)
        axis.set_title(name)
        axis.set_xlabel("touches in the map, %")
        axis.set_ylabel("median RMSE, mm")
        axis.set_yscale("log")
        axis.legend(fontsize=7)
    return figure


def confusion_figure(confusion: np.ndarray, object_ids, *, counted: str = "touches") -> Figure:
    """Identification confusion matrix (rows: true object, columns: identified), row-normalised;
    ``counted`` names what a row counts (held-out touches, episodes) for the colour bar."""
    confusion = np.asarray(confusion, float)
    rates = confusion / np.maximum(confusion.sum(axis=1, keepdims=True), 1)
    size = 1.0 + 0.8 * len(object_ids)
    figure = Figure(figsize=(size + 1.5, size))
    axis = figure.subplots()
    image = axis.imshow(rates, vmin=0, vmax=1, cmap="Blues")
    for i in range(len(object_ids)):
        for j in range(len(object_ids)):
            axis.text(j, i, f"{100 * rates[i, j]:.0f}", ha="center", va="center",
                      color="white" if rates[i, j] > 0.5 else "black", fontsize=8)
    axis.set_xticks(range(len(object_ids)), object_ids, rotation=45, ha="right")
    axis.set_yticks(range(len(object_ids)), object_ids)
    axis.set_xlabel("identified as")
    axis.set_ylabel("true object")
    figure.colorbar(image, ax=axis, label=f"fraction of {counted}")
    return figure
