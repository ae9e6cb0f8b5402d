"""The compact form of a map's imprints: heightmaps and contact masks in one float16 array,
contact points as pixel indices.

A *packed heightmap* holds the indentation depth h >= 0 (mm) in float16, with the contact mask
in the sign bit: ``+h`` in contact, ``-h`` (``-0.0`` for h = 0) off it. float16 keeps the depth
to within 2^-11 of its value (0.0005 mm at 1 mm, finer near rest), two orders of magnitude below
the shape model's error (0.06 mm, paper section IV), in half the bytes of float32 and without a
separate mask.

A map's contact points are heightmap pixels (:func:`~tactojax.mapping.sample_contact_points`),
so a pixel index (row * W + col) per point stores them: the point is the pixel's (x, y, -h) and
its normal comes from the heightmap's central differences there, exactly as at map time.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Float16, Int

from tactojax.geometry import pixel_grid


def pack_heightmaps(heightmaps: Float[Array, "*batch H W"], masks: Bool[Array, "*batch H W"]) -> Float16[Array, "*batch H W"]:
    """Heightmaps (mm, clipped at 0) and contact masks as one float16 array (see the module docstring)."""
    height = jnp.maximum(jnp.asarray(heightmaps, jnp.float32), 0.0).astype(jnp.float16)
    return jnp.where(jnp.asarray(masks, bool), height, -height)


def unpack_heightmaps(packed: Float16[Array, "*batch H W"]) -> tuple[Float[Array, "*batch H W"], Bool[Array, "*batch H W"]]:
    """(heightmaps float32 mm, contact masks) of packed heightmaps."""
    return jnp.abs(packed).astype(jnp.float32), ~jnp.signbit(packed)


def pixel_index_dtype(height_px: int, width_px: int):
    """The smallest unsigned type that indexes every pixel of an H x W image."""
    return np.uint16 if height_px * width_px <= np.iinfo(np.uint16).max + 1 else np.int32


def pixel_points(
    packed: Float16[Array, "H W"], pixels: Int[Array, "P"], mm_per_px: float
) -> tuple[Float[Array, "P 3"], Float[Array, "P 3"]]:
    """Points (x, y, -h) and unit normals, sensor frame, at pixels (row * W + col) of one packed
    heightmap: :func:`~tactojax.geometry.heightmap_to_points` and
    :func:`~tactojax.geometry.heightmap_normals` read at those pixels, computed from the five
    pixels around each (central differences, one-sided on the border, as ``jnp.gradient``).

    Args:
        packed: (H, W) packed heightmap.
        pixels: (P,) flat pixel indices.
        mm_per_px: pixel pitch, mm.

    Returns:
        points (P, 3) mm and normals (P, 3).
    """
    height_px, width_px = packed.shape
    flat = jnp.abs(packed).reshape(-1).astype(jnp.float32)
    pixels = jnp.asarray(pixels, jnp.int32)
    row, col = pixels // width_px, pixels % width_px

    def derivative(low, high, index):
        return (flat[index(high)] - flat[index(low)]) / (high - low).astype(jnp.float32)

    dh_dcol = derivative(jnp.maximum(col - 1, 0), jnp.minimum(col + 1, width_px - 1), lambda c: row * width_px + c)
    dh_drow = derivative(jnp.maximum(row - 1, 0), jnp.minimum(row + 1, height_px - 1), lambda r: r * width_px + col)
    xy = pixel_grid(height_px, width_px, mm_per_px).reshape(-1, 2)[pixels]
    points = jnp.concatenate([xy, -flat[pixels][:, None]], axis=-1)
    normals = jnp.stack([-dh_dcol / mm_per_px, -dh_drow / mm_per_px, -jnp.ones_like(dh_dcol)], axis=-1)
    return points, normals / jnp.linalg.norm(normals, axis=-1, keepdims=True)


def points_to_pixels(points: Float[Array, "*batch P 3"], height_px: int, width_px: int, mm_per_px: float,
                     *, tolerance_px: float = 1e-3) -> np.ndarray:
    """Flat pixel indices of points that lie on the pixel grid (a version-1 map file's points).

    Raises:
        ValueError: a point is off the grid by more than ``tolerance_px`` or outside the image.
    """
    points = np.asarray(points, np.float64)
    col = points[..., 0] / mm_per_px + (width_px - 1) / 2.0
    row = points[..., 1] / mm_per_px + (height_px - 1) / 2.0
    col_index, row_index = np.round(col), np.round(row)
    off = max(np.abs(col - col_index).max(initial=0.0), np.abs(row - row_index).max(initial=0.0))
    inside = (col_index >= 0) & (col_index < width_px) & (row_index >= 0) & (row_index < height_px)
    if off > tolerance_px or not np.all(inside):
        raise ValueError(f"points are not on the {height_px} x {width_px} pixel grid (off by up to {off:.3g} px)")
    return (row_index * width_px + col_index).astype(pixel_index_dtype(height_px, width_px))
