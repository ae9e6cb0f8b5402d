"""Heightmap reconstruction errors (paper section IV, Table I).

The *contact patch* is the ground-truth contact mask: the pixels where the object penetrates
the undeformed gel plane (``Contact.mask`` of the simulator; the annotated disc for real ball
presses). ``patch_rmse`` is the RMSE of the predicted heightmap over those pixels, the paper's
"RMSE w.r.t. the size of the contact patch"; ``image_rmse`` is over every pixel, so heights
predicted where nothing touches count too; ``mask_iou`` compares predicted and true masks.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float


def heightmap_errors(
    predicted: Float[Array, "H W"],
    predicted_mask: Bool[Array, "H W"],
    true: Float[Array, "H W"],
    true_mask: Bool[Array, "H W"],
) -> dict[str, Float[Array, ""]]:
    """Errors of one predicted heightmap against the ground truth.

    Returns:
        ``patch_rmse`` (mm, NaN when the true patch is empty), ``image_rmse`` (mm) and
        ``mask_iou`` (1 when both masks are empty).
    """
    squared = (predicted - true) ** 2
    patch_pixels = jnp.sum(true_mask)
    patch_rmse = jnp.sqrt(jnp.sum(jnp.where(true_mask, squared, 0.0)) / jnp.maximum(patch_pixels, 1))
    union = jnp.sum(predicted_mask | true_mask)
    intersection = jnp.sum(predicted_mask & true_mask)
    return {
        "patch_rmse": jnp.where(patch_pixels > 0, patch_rmse, jnp.nan),
        "image_rmse": jnp.sqrt(jnp.mean(squared)),
        "mask_iou": jnp.where(union > 0, intersection / jnp.maximum(union, 1), 1.0),
    }


batch_heightmap_errors = jax.jit(jax.vmap(heightmap_errors))
""":func:`heightmap_errors` over a leading batch axis."""


def summarize_errors(errors: dict[str, np.ndarray], object_ids: np.ndarray) -> dict[str, dict]:
    """Mean and standard deviation of each error, per object and over all (``"all"``).

    Args:
        errors: per-image arrays from :func:`batch_heightmap_errors`.
        object_ids: (N,) object of each image.

    Returns:
        ``{object_id | "all": {"count": n, "<error>": mean, "<error>_std": std, ...}}``.
    """
    object_ids = np.asarray(object_ids)
    groups = {name: object_ids == name for name in dict.fromkeys(object_ids.tolist())}
    groups["all"] = np.ones(len(object_ids), bool)
    summary = {}
    for name, selected in groups.items():
        row = {"count": int(selected.sum())}
        for metric, values in errors.items():
            values = np.asarray(values, np.float64)[selected]
            values = values[np.isfinite(values)]
            row[metric] = float(values.mean()) if len(values) else float("nan")
            row[f"{metric}_std"] = float(values.std()) if len(values) else float("nan")
        summary[name] = row
    return summary


def evaluate_shape_model(model, data, *, batch_size: int = 32, background=None,
                         transform=None, progress: bool = False) -> dict[str, np.ndarray]:
    """Per-image errors of a model on (image, heightmap, mask) pairs.

    Args:
        model: a :class:`tactojax.shape.ShapeModel`.
        data: a :class:`tactojax.shape.ShapeData` with the model's image size.
        batch_size: images per jitted call (the last batch is padded, so it compiles once).
        background: a recaptured background frame to use instead of the model's.
        transform: optional ``f(images (B, H, W, 3) float) -> images`` applied before
            prediction (lighting or noise changes for robustness studies).

    Returns:
        ``{"patch_rmse", "image_rmse", "mask_iou"}``, each (N,) float.
    """
    from tqdm.auto import tqdm

    from tactojax.shape._predict import check_image, predict_batch

    check_image(model, data.images)
    if background is not None:
        model = model.replace(background=jnp.asarray(background, jnp.float32))
    results: dict[str, list] = {}
    for start in tqdm(range(0, len(data), batch_size), desc="evaluate", disable=not progress):
        rows = np.arange(start, min(start + batch_size, len(data)))
        padded = np.pad(rows, (0, batch_size - len(rows)), mode="edge")
        images = data.images_float(padded)
        if transform is not None:
            images = transform(images)
        heightmaps, masks = predict_batch(model, images)
        errors = batch_heightmap_errors(heightmaps, masks, data.heightmaps[padded], data.masks[padded])
        for name, values in errors.items():
            results.setdefault(name, []).append(np.asarray(values)[: len(rows)])
    return {name: np.concatenate(values) for name, values in results.items()}
