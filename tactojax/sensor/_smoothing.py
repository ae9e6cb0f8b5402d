"""Separable Gaussian smoothing of single-channel images (pure JAX)."""

from __future__ import annotations

import math

import jax.numpy as jnp
from jaxtyping import Array, Float


def gaussian_matrix(size: int, sigma_px: float) -> Float[Array, "N N"]:
    """(N, N) matrix that blurs a length-N signal with a Gaussian, zero outside the signal.

    Row i holds the normalised kernel (truncated at 3 sigma) centred on sample i. A dense
    matrix product is much faster on CPU than XLA's convolution for wide single-channel kernels.
    """
    radius = max(1, int(math.ceil(3.0 * sigma_px)))
    kernel = jnp.exp(-0.5 * (jnp.arange(-radius, radius + 1, dtype=jnp.float32) / sigma_px) ** 2)
    kernel = kernel / kernel.sum()
    offset = jnp.arange(size)[None, :] - jnp.arange(size)[:, None]  # column - row
    inside = jnp.abs(offset) <= radius
    return jnp.where(inside, kernel[jnp.clip(offset + radius, 0, 2 * radius)], 0.0)


def gaussian_blur(image: Float[Array, "H W"], sigma_px: float) -> Float[Array, "H W"]:
    """Blur an image with a Gaussian of ``sigma_px`` pixels; zero outside the image.

    Zero padding is right for heightmaps: outside the imaged gel there is no indentation.
    """
    if sigma_px <= 0:
        return image
    rows = gaussian_matrix(image.shape[0], sigma_px)
    columns = gaussian_matrix(image.shape[1], sigma_px)
    return rows @ image @ columns.T
