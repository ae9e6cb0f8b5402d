"""The sensor's pixel grid in millimetres (sensor frame)."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float


def pixel_grid(height_px: int, width_px: int, mm_per_px: float) -> Float[Array, "H W 2"]:
    """Sensor-frame (x, y) of every pixel centre, in mm.

    The sensor frame's origin is the centre of the undeformed gel surface, x runs along image
    columns and y along image rows (DESIGN.md). The rectified tactile image is treated as an
    orthographic view of the gel, so pixel (row r, column c) sits at
    ``x = (c - (W - 1) / 2) * mm_per_px`` and ``y = (r - (H - 1) / 2) * mm_per_px``.

    Args:
        height_px: image rows H (static).
        width_px: image columns W (static).
        mm_per_px: pixel pitch on the gel surface, mm.

    Returns:
        (H, W, 2) array of (x, y) in mm.
    """
    xs = (jnp.arange(width_px, dtype=jnp.float32) - (width_px - 1) / 2.0) * mm_per_px
    ys = (jnp.arange(height_px, dtype=jnp.float32) - (height_px - 1) / 2.0) * mm_per_px
    x, y = jnp.meshgrid(xs, ys, indexing="xy")
    return jnp.stack([x, y], axis=-1)
