"""Colour augmentation for training (paper section IV: random variations of the 3 channels)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray


def augment_colors(
    key: PRNGKeyArray,
    image: Float[Array, "H W 3"],
    *,
    max_gain: float = 0.15,
    max_offset: float = 0.05,
    max_gamma: float = 0.15,
) -> Float[Array, "H W 3"]:
    """Random per-channel gain, offset and gamma, as a lighting/camera change would give.

    Each channel c becomes ``clip((g_c * I_c + o_c) ** gamma_c, 0, 1)`` with
    ``g_c ~ U(1 - max_gain, 1 + max_gain)``, ``o_c ~ U(-max_offset, max_offset)`` and
    ``log(gamma_c) ~ U(-max_gamma, max_gamma)``.

    Args:
        key: PRNG key.
        image: (H, W, 3) RGB in [0, 1].

    Returns:
        (H, W, 3) augmented RGB in [0, 1].
    """
    gain_key, offset_key, gamma_key = jax.random.split(key, 3)
    gain = jax.random.uniform(gain_key, (3,), minval=1 - max_gain, maxval=1 + max_gain)
    offset = jax.random.uniform(offset_key, (3,), minval=-max_offset, maxval=max_offset)
    gamma = jnp.exp(jax.random.uniform(gamma_key, (3,), minval=-max_gamma, maxval=max_gamma))
    shifted = jnp.clip(gain * image + offset, 1e-6, 1.0)  # > 0 keeps d(x**gamma) finite
    return jnp.clip(shifted**gamma, 0.0, 1.0)
