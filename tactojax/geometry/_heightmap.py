"""Heightmap -> points and normals in the sensor frame."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from tactojax.geometry._pixels import pixel_grid


def heightmap_gradient(
    heightmap: Float[Array, "H W"], mm_per_px: float
) -> Float[Array, "H W 2"]:
    """Slope (dh/dx, dh/dy) of a heightmap, dimensionless (mm per mm).

    Central differences inside the image, one-sided differences on the border (``jnp.gradient``).

    Args:
        heightmap: (H, W) indentation depth, mm.
        mm_per_px: pixel pitch, mm.

    Returns:
        (H, W, 2): derivative along x (columns) and along y (rows).
    """
    dh_drow, dh_dcol = jnp.gradient(heightmap)
    return jnp.stack([dh_dcol, dh_drow], axis=-1) / mm_per_px


def heightmap_to_points(
    heightmap: Float[Array, "H W"], mm_per_px: float
) -> Float[Array, "H W 3"]:
    """Contact surface points in the sensor frame, mm.

    The gel is pushed into -z by the indentation, so the touched surface at pixel (x, y) is the
    point (x, y, -h). Points are returned for every pixel; pair them with the contact mask.

    Args:
        heightmap: (H, W) indentation depth h >= 0, mm.
        mm_per_px: pixel pitch, mm.

    Returns:
        (H, W, 3) points p_sensor in mm.
    """
    height_px, width_px = heightmap.shape
    xy = pixel_grid(height_px, width_px, mm_per_px)
    return jnp.concatenate([xy, -heightmap[..., None]], axis=-1)


def heightmap_normals(
    heightmap: Float[Array, "H W"], mm_per_px: float
) -> Float[Array, "H W 3"]:
    """Unit normals of the touched object's surface, in the sensor frame.

    The surface is z = -h(x, y); its normal pointing out of the object (towards the sensor,
    roughly -z) is (-dh/dx, -dh/dy, -1) / norm.

    Args:
        heightmap: (H, W) indentation depth, mm.
        mm_per_px: pixel pitch, mm.

    Returns:
        (H, W, 3) unit normals n_sensor.
    """
    slope = heightmap_gradient(heightmap, mm_per_px)
    normals = jnp.concatenate([-slope, -jnp.ones_like(slope[..., :1])], axis=-1)
    return normals / jnp.linalg.norm(normals, axis=-1, keepdims=True)


def contact_points(
    heightmap: Float[Array, "H W"], mask: Bool[Array, "H W"], mm_per_px: float
) -> tuple[Float[Array, "H*W 3"], Float[Array, "H*W 3"], Bool[Array, "H*W"]]:
    """Flattened points, normals and valid mask of one imprint (fixed size H*W).

    Args:
        heightmap: (H, W) indentation depth, mm.
        mask: (H, W) contact mask.
        mm_per_px: pixel pitch, mm.

    Returns:
        points (H*W, 3) mm, normals (H*W, 3), valid (H*W,) - all in the sensor frame.
    """
    points = heightmap_to_points(heightmap, mm_per_px).reshape(-1, 3)
    normals = heightmap_normals(heightmap, mm_per_px).reshape(-1, 3)
    return points, normals, mask.reshape(-1)
