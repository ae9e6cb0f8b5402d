"""The classical reconstruction, no learning: colour change -> slope lookup table + Poisson.

This is how GelSight users calibrate a gel (Johnson & Adelson 2009): press a ball of known
radius, read the slope the ball imposes at every contact pixel, and tabulate the mean slope
for each colour change against the background frame. At run time every pixel looks its colour
change up (trilinear interpolation in the table) and the slope field is integrated.
"""

from __future__ import annotations

import numpy as np
import scipy.ndimage
from jax.scipy.ndimage import map_coordinates
import jax.numpy as jnp
from jaxtyping import Array, Float


def fit_lookup_table(
    color_change: np.ndarray, slope: np.ndarray, *, bins: int = 24, color_range: float | None = None
) -> tuple[np.ndarray, float]:
    """Tabulate the mean slope per colour-change bin, filling empty bins from their neighbours.

    Args:
        color_change: (N, 3) image minus background, RGB in [-1, 1].
        slope: (N, 2) surface slope at the same pixels (dh/dx, dh/dy), mm per mm.
        bins: bins per colour channel.
        color_range: the table covers [-color_range, color_range] per channel; default the
            99.9th percentile of ``|color_change|``.

    Returns:
        (table (bins, bins, bins, 2) float32, color_range).
    """
    color_change = np.asarray(color_change, np.float64).reshape(-1, 3)
    slope = np.asarray(slope, np.float64).reshape(-1, 2)
    if len(color_change) == 0:
        raise ValueError("no calibration pixels: every contact mask is empty")
    if color_range is None:
        color_range = float(max(np.percentile(np.abs(color_change), 99.9), 1e-3))
    index = _bin_index(color_change, bins, color_range)
    flat = np.ravel_multi_index(index.T, (bins,) * 3)
    counts = np.bincount(flat, minlength=bins**3)
    sums = np.stack([np.bincount(flat, weights=slope[:, k], minlength=bins**3) for k in range(2)], -1)
    filled = counts > 0
    table = np.zeros((bins**3, 2))
    table[filled] = sums[filled] / counts[filled, None]
    table = table.reshape(bins, bins, bins, 2)
    # Empty bins take the value of the nearest filled bin.
    _, nearest = scipy.ndimage.distance_transform_edt(~filled.reshape((bins,) * 3), return_indices=True)
    table = table[tuple(nearest)]
    return table.astype(np.float32), color_range


def lookup_slope(
    table: Float[Array, "B B B 2"], color_range: float, color_change: Float[Array, "H W 3"]
) -> Float[Array, "H W 2"]:
    """Slope of every pixel by trilinear interpolation in a lookup table (pure JAX).

    Args:
        table: (B, B, B, 2) mean slope per colour-change bin, from :func:`fit_lookup_table`.
        color_range: half-width of the colour-change range the table covers.
        color_change: (H, W, 3) image minus background.

    Returns:
        (H, W, 2) slope, mm per mm.
    """
    bins = table.shape[0]
    # Bin centres sit at integer coordinates 0 .. B-1.
    coords = (color_change / color_range + 1.0) * 0.5 * bins - 0.5
    coords = jnp.clip(coords, 0.0, bins - 1.0)
    flat_coords = [coords[..., k].reshape(-1) for k in range(3)]
    channels = [
        map_coordinates(table[..., k], flat_coords, order=1, mode="nearest").reshape(coords.shape[:2])
        for k in range(2)
    ]
    return jnp.stack(channels, axis=-1)


def _bin_index(color_change: np.ndarray, bins: int, color_range: float) -> np.ndarray:
    scaled = (color_change / color_range + 1.0) * 0.5 * bins
    return np.clip(np.floor(scaled), 0, bins - 1).astype(np.int64)


def fit_lookup_model(
    data,
    *,
    background: np.ndarray | None = None,
    bins: int = 24,
    max_pixels: int = 2_000_000,
    threshold_pairs: int = 200,
    seed: int = 0,
):
    """The classical model fitted to (image, heightmap, mask) pairs: table, range, mask threshold.

    Every contact pixel, plus an equal number of pixels from anywhere, contributes its colour
    change and the true slope of its heightmap. The contact threshold on the reconstructed
    height is the one that maximises the mean mask IoU on the pairs themselves.

    Args:
        data: a :class:`tactojax.shape.ShapeData`.
        background: the no-contact frame, (H, W, 3) in [0, 1]; default estimated from ``data``.
        bins: table bins per colour channel.
        max_pixels: cap on the pixels used (sampled with ``seed``).
        threshold_pairs: pairs reconstructed to pick the contact threshold
            (:func:`fit_mask_threshold`); 0 leaves it at 0 for the caller to fit.

    Returns:
        A :class:`tactojax.shape.ShapeModel` with preset ``lookup``.
    """
    import jax

    from tactojax.geometry import heightmap_gradient
    from tactojax.shape._data import estimate_background
    from tactojax.shape._predict import LOOKUP, ShapeModel

    if background is None:
        background = estimate_background(data)
    rng = np.random.default_rng(seed)
    slopes = np.asarray(jax.vmap(lambda h: heightmap_gradient(h, data.mm_per_px))(
        jax.numpy.asarray(data.heightmaps)))
    changes = data.images.astype(np.float32) / 255.0 - background
    contact = data.masks.reshape(-1)
    anywhere = rng.random(contact.size) < contact.mean()
    chosen = np.flatnonzero(contact | anywhere)
    if len(chosen) > max_pixels:
        chosen = rng.choice(chosen, max_pixels, replace=False)
    table, color_range = fit_lookup_table(changes.reshape(-1, 3)[chosen], slopes.reshape(-1, 2)[chosen],
                                          bins=bins)
    params = {"table": table, "color_range": np.float32(color_range),
              "mask_threshold_mm": np.float32(0.0)}
    model = ShapeModel(params=params, background=np.asarray(background, np.float32), preset=LOOKUP,
                       mm_per_px=data.mm_per_px, sensor=data.sensor)
    if not threshold_pairs:
        return model
    return fit_mask_threshold(model, data, max_pairs=threshold_pairs, seed=seed)[0]


def fit_mask_threshold(model, data, *, max_pairs: int = 200, seed: int = 0):
    """Set ``params["mask_threshold_mm"]`` to the height threshold that best reproduces the
    true contact masks of (up to ``max_pairs`` of) ``data`` (mean IoU), for models whose
    contact is "reconstructed height above a threshold" (``lookup``, ``fast``, ``tiny``).

    Thresholds are searched from 0 to the 99.9th percentile of the reconstructed heights.

    Returns:
        (the model with its threshold set, the mean IoU it achieves on those pairs).
    """
    import jax

    from tactojax.shape._calibrate import best_mask_threshold
    from tactojax.shape._predict import raw_prediction

    rows = np.random.default_rng(seed).choice(len(data), min(len(data), max_pairs), replace=False)
    heights = jax.jit(jax.vmap(lambda image: raw_prediction(model, image)[0]))(data.images_float(rows))
    heights = np.asarray(heights)
    thresholds = np.linspace(0.0, max(float(np.percentile(heights, 99.9)), 1e-3), 101)
    threshold, ious = best_mask_threshold(heights, data.masks[rows], thresholds)
    params = dict(model.params)
    params["mask_threshold_mm"] = np.float32(threshold)
    return model.replace(params=params), float(ious.max())
