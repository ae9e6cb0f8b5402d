"""Separable Gaussian smoothing of single-channel images (pure JAX)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float


def gaussian_kernel(sigma_px: float) -> Float[Array, "K"]:
    """Normalised 1-D Gaussian kernel truncated at 3 sigma (static size)."""
    radius = max(1, int(math.ceil(3.0 * sigma_px)))
    offsets = jnp.arange(-radius, radius + 1, dtype=jnp.float32)
    kernel = jnp.exp(-0.5 * (offsets / sigma_px) ** 2)
    return kernel / kernel.sum()


def gaussian_blur(image: Float[Array, "H W"], sigma_px: float) -> Float[Array, "H W"]:
    """Blur an image with a Gaussian of ``sigma_px`` pixels; zero outside the image.

    Zero padding is right for heightmaps: outside the imaged gel there is no indentation.
    """
    if sigma_px <= 0:
        return image
    kernel = gaussian_kernel(sigma_px)
    size = kernel.shape[0]
    x = image[None, None]
    dimension_numbers = ("NCHW", "OIHW", "NCHW")
    x = jax.lax.conv_general_dilated(
        x, kernel.reshape(1, 1, size, 1), (1, 1), "SAME", dimension_numbers=dimension_numbers
    )
    x = jax.lax.conv_general_dilated(
        x, kernel.reshape(1, 1, 1, size), (1, 1), "SAME", dimension_numbers=dimension_numbers
    )
    return x[0, 0]
