"""Robustness of a shape model to lighting and camera changes it never saw in training."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from tactojax.sensor import augment_colors
from tactojax.shape._metrics import evaluate_shape_model, summarize_errors

UNSEEN_LIGHTING = {"max_gain": 0.3, "max_offset": 0.08, "max_gamma": 0.3}
"""Twice the training augmentation's gain and gamma range (``augment_colors`` defaults 0.15)."""


def robustness_study(model, data, *, trials: int = 3, extra_noise_std: float = 0.02,
                     seed: int = 0, batch_size: int = 32) -> dict[str, dict]:
    """Errors under nominal conditions, unseen lighting, extra camera noise, and both.

    * ``lighting``: each trial draws one per-channel gain/offset/gamma change from
      :data:`UNSEEN_LIGHTING` and applies it to every test image; models that use a background
      frame get the frame recaptured under the same lighting (as a user would).
    * ``noise``: Gaussian pixel noise of ``extra_noise_std`` on top of the sensor's own.

    Returns:
        ``{condition: summary over all pairs (see summarize_errors, key "all")}``.
    """
    key = jax.random.key(seed)
    results = {"nominal": _overall(evaluate_shape_model(model, data, batch_size=batch_size), data)}
    for condition in ("lighting", "noise", "lighting+noise"):
        trial_errors = []
        for trial in range(trials):
            light_key, noise_key = jax.random.split(jax.random.fold_in(key, trial))
            transform, background = _condition(model, condition, light_key, noise_key, extra_noise_std)
            trial_errors.append(evaluate_shape_model(model, data, batch_size=batch_size,
                                                     background=background, transform=transform))
        merged = {k: np.concatenate([e[k] for e in trial_errors]) for k in trial_errors[0]}
        results[condition] = _overall(merged, data, repeat=trials)
    return results


def _condition(model, condition, light_key, noise_key, noise_std):
    lighting = "lighting" in condition
    noise = "noise" in condition

    batches = iter(range(1 << 30))  # fresh noise for every batch

    def transform(images):
        images = jnp.asarray(images)
        if lighting:
            images = jax.vmap(lambda image: augment_colors(light_key, image, **UNSEEN_LIGHTING))(images)
        if noise:
            key = jax.random.fold_in(noise_key, next(batches))
            images = jnp.clip(images + noise_std * jax.random.normal(key, images.shape), 0.0, 1.0)
        return images

    background = augment_colors(light_key, model.background, **UNSEEN_LIGHTING) if lighting else None
    return transform, background


def _overall(errors, data, repeat: int = 1) -> dict:
    return summarize_errors(errors, np.tile(data.object_ids, repeat))["all"]
