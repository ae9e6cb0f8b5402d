"""Optics: gel heightmap -> RGB tactile image (pure JAX, differentiable in the heightmap)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from tactojax.geometry import heightmap_gradient
from tactojax.sensor._spec import PhotometricOptics, PolynomialTableOptics, SensorSpec


def render_image(spec: SensorSpec, heightmap: Float[Array, "H W"]) -> Float[Array, "H W 3"]:
    """Noise-free tactile image of a gel indentation.

    Args:
        spec: the sensor; its ``optics`` picks the model.
        heightmap: (H, W) gel indentation, mm.

    Returns:
        (H, W, 3) RGB image in [0, 1].
    """
    slope = heightmap_gradient(heightmap, spec.mm_per_px)
    if isinstance(spec.optics, PhotometricOptics):
        signal = _photometric_signal(spec.optics, slope)
    elif isinstance(spec.optics, PolynomialTableOptics):
        signal = _polynomial_table_signal(spec.optics, slope)
    else:
        raise TypeError(f"unknown optics model {type(spec.optics).__name__}")
    return jnp.clip(spec.optics.background + signal, 0.0, 1.0)


def add_sensor_noise(
    key: PRNGKeyArray, spec: SensorSpec, image: Float[Array, "H W 3"]
) -> Float[Array, "H W 3"]:
    """Add the camera's Gaussian pixel noise (``spec.noise_std``) and clip to [0, 1]."""
    noise = spec.noise_std * jax.random.normal(key, image.shape, image.dtype)
    return jnp.clip(image + noise, 0.0, 1.0)


def _photometric_signal(
    optics: PhotometricOptics, slope: Float[Array, "H W 2"]
) -> Float[Array, "H W 3"]:
    # Membrane normal facing the camera (-z side): -(h_x, h_y, 1) / norm.
    normals = -jnp.concatenate([slope, jnp.ones_like(slope[..., :1])], axis=-1)
    normals = normals * jax.lax.rsqrt(1.0 + jnp.sum(slope**2, axis=-1, keepdims=True))
    flat_normal = jnp.array([0.0, 0.0, -1.0])
    shading = jnp.maximum(normals @ optics.light_directions.T, 0.0)  # (H, W, K)
    flat_shading = jnp.maximum(optics.light_directions @ flat_normal, 0.0)  # (K,)
    signal = (shading - flat_shading) @ optics.light_colors  # (H, W, 3)
    return optics.gain * optics.vignetting[..., None] * signal


def _polynomial_table_signal(
    optics: PolynomialTableOptics, slope: Float[Array, "H W 2"]
) -> Float[Array, "H W 3"]:
    num_bins = optics.table.shape[0]
    height_px, width_px = optics.background.shape[:2]
    slope_x, slope_y = slope[..., 0], slope[..., 1]
    # Slope magnitude as an angle in [0, pi/2] and direction in [-pi, pi], as bin coordinates.
    # The small epsilon keeps the gradient of the norm finite on flat gel.
    magnitude = jnp.arctan(jnp.sqrt(slope_x**2 + slope_y**2 + 1e-12))
    direction = jnp.arctan2(slope_y, slope_x)
    u = magnitude / (0.5 * jnp.pi) * (num_bins - 1)
    v = (direction + jnp.pi) / (2.0 * jnp.pi) * (num_bins - 1)
    coefficients = _bilinear_lookup(optics.table, u, v)  # (H, W, 6, 3)
    # Pixel coordinates of the calibration frames (full resolution), x along columns.
    x = jnp.arange(width_px, dtype=jnp.float32) * (optics.calibration_width_px / width_px)
    y = jnp.arange(height_px, dtype=jnp.float32) * (optics.calibration_height_px / height_px)
    x, y = jnp.meshgrid(x, y, indexing="xy")
    features = jnp.stack([x * x, y * y, x * y, x, y, jnp.ones_like(x)], axis=-1)
    return jnp.einsum("hwf,hwfc->hwc", features, coefficients)


def _bilinear_lookup(
    table: Float[Array, "B B ..."], u: Float[Array, "H W"], v: Float[Array, "H W"]
) -> Float[Array, "H W ..."]:
    """Bilinear interpolation of ``table`` at fractional bin coordinates (u, v), clamped."""
    last = table.shape[0] - 1
    u = jnp.clip(u, 0.0, last)
    v = jnp.clip(v, 0.0, last)
    u0 = jnp.clip(jnp.floor(u), 0, last - 1).astype(jnp.int32)
    v0 = jnp.clip(jnp.floor(v), 0, last - 1).astype(jnp.int32)
    du = (u - u0)[..., None, None]
    dv = (v - v0)[..., None, None]
    return (
        table[u0, v0] * (1 - du) * (1 - dv)
        + table[u0 + 1, v0] * du * (1 - dv)
        + table[u0, v0 + 1] * (1 - du) * dv
        + table[u0 + 1, v0 + 1] * du * dv
    )
