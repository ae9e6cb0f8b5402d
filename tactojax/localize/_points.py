"""Fixed-size point sets drawn from a touch: what ICP and the likelihood read.

Pixels are drawn by a fixed random order of the image (:func:`pixel_priority`), so the same
touch always gives the same points (repeatable in a control loop, no random numbers to
generate), and every set has a fixed size (padded with invalid points), so nothing recompiles.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from tactojax import _struct as struct
from tactojax.geometry import pixel_grid
from tactojax.localize._map import Touch

POINTS_PER_TOUCH = 128
"""Contact points drawn from a touch for the paper's ICP baselines."""
FREE_HEIGHT_MM = 0.08
"""Outside the mask, a pixel indented less than this is free space (no contact), mm."""
FREE_BAND_MM = 5.0
"""No-contact points are drawn first among the free pixels within this distance of the touch's
contact (along rows and columns: a square neighbourhood), mm. There they tell where the
object's edges are not: a pose that slid the object a few millimetres would press the gel just
beside the contact, while the free pixels far from it stay free under every pose near the truth
(the paper's negative information, section VIII). Drawn uniformly over the whole pad, most of the
64 no-contact points fell far from the contact and said nothing."""


@functools.lru_cache(maxsize=8)
def pixel_priority(height_px: int, width_px: int, seed: int = 0) -> np.ndarray:
    """A fixed random order of the pixels (in [0, 1)): the same draw for every touch."""
    order = np.random.default_rng(seed).permutation(height_px * width_px)
    return (order / (height_px * width_px)).astype(np.float32)


def draw_pixels(
    flat: Bool[Array, "N"], priority: np.ndarray, count: int, first: Bool[Array, "N"] | None = None
) -> tuple[Int[Array, "count"], Bool[Array, "count"]]:
    """``count`` pixels drawn uniformly without replacement where ``flat`` holds, by the fixed
    order ``priority`` (:func:`pixel_priority`), padded with pixels where it does not; and valid.
    With ``first``, the pixels where both hold are drawn before the other pixels of ``flat``."""
    rank = flat.astype(jnp.float32)
    if first is not None:
        rank = rank + (first & flat).astype(jnp.float32)
    _, index = jax.lax.top_k(jnp.asarray(priority) + rank, count)
    return index, flat[index]


def near_contact(mask: Bool[Array, "H W"], radius_px: int) -> Bool[Array, "H W"]:
    """Pixels within ``radius_px`` rows and columns of a pixel of ``mask`` (a square dilation:
    along each axis, a window sum from a cumulative sum, whatever the radius; a windowed maximum
    took 1 ms on a CPU at 25 px)."""
    if radius_px <= 0:
        return mask
    grown = mask.astype(jnp.int32)
    for axis in (0, 1):
        along = jnp.moveaxis(grown, axis, 0)
        total = jnp.cumsum(jnp.pad(along, ((radius_px + 1, radius_px), (0, 0))), axis=0)
        grown = jnp.moveaxis(total[2 * radius_px + 1:] - total[:-(2 * radius_px + 1)], 0, axis)
    return grown > 0


def contact_points(
    touch: Touch, mm_per_px: float, count: int = POINTS_PER_TOUCH
) -> tuple[Float[Array, "P 3"], Bool[Array, "P"]]:
    """``count`` contact points of a touch, (x, y, -height) in its sensor frame, mm, drawn from
    its mask; and which are valid. Differentiable with respect to ``touch.heightmap`` (the
    pixels are chosen from the mask)."""
    height_px, width_px = touch.heightmap.shape
    index, valid = draw_pixels(touch.mask.reshape(-1), pixel_priority(height_px, width_px), count)
    row, col = index // width_px, index % width_px
    x = (col - (width_px - 1) / 2.0) * mm_per_px
    y = (row - (height_px - 1) / 2.0) * mm_per_px
    return jnp.stack([x, y, -touch.heightmap.reshape(-1)[index]], axis=-1), valid


@struct.dataclass
class TouchEvidence:
    """What one touch says to the belief's likelihood, as fixed-size point sets in its sensor frame (mm)."""

    contact: Float[Array, "P 3"]
    """Points where the gel felt the object: (x, y, -height)."""
    contact_valid: Bool[Array, "P"]
    free: Float[Array, "F 3"]
    """Points of the gel plane where it felt nothing: (x, y, 0)."""
    free_valid: Bool[Array, "F"]


def touch_evidence(touch: Touch, mm_per_px: float, *, contact_count: int = 64, free_count: int = 64,
                   free_band_mm: float = FREE_BAND_MM) -> TouchEvidence:
    """The evidence of one touch: contact points from its mask (a uniform draw), no-contact
    points elsewhere (outside the mask and indented less than ``FREE_HEIGHT_MM``), drawn first
    within ``free_band_mm`` of the contact (:data:`FREE_BAND_MM`; 0: uniformly over the pad), then
    from the rest. A touch without contact has no valid point."""
    heightmap, mask = touch.heightmap, touch.mask
    height_px, width_px = heightmap.shape
    flat_height = heightmap.reshape(-1)
    x, y = pixel_grid(height_px, width_px, mm_per_px).reshape(-1, 2).T
    contact_index, contact_valid = draw_pixels(mask.reshape(-1), pixel_priority(height_px, width_px, 1), contact_count)
    free = ~mask.reshape(-1) & (flat_height < FREE_HEIGHT_MM)
    band = near_contact(mask, int(round(free_band_mm / mm_per_px))).reshape(-1) if free_band_mm > 0 else None
    free_index, free_valid = draw_pixels(free, pixel_priority(height_px, width_px, 2), free_count, first=band)
    contact = jnp.stack([x[contact_index], y[contact_index], -flat_height[contact_index]], axis=-1)
    free_xyz = jnp.stack([x[free_index], y[free_index], jnp.zeros(free_count)], axis=-1)
    return TouchEvidence(contact=contact, contact_valid=contact_valid & jnp.any(mask),
                         free=free_xyz, free_valid=free_valid & jnp.any(mask))
