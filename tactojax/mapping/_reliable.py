"""Which predicted contact pixels a shape fit can rely on: contact, not skirt, and observed depth.

A predicted contact mask is more than the contact. Two kinds of pixel mislead a least-squares
fit of the object's surface:

* *Membrane skirt.* Beyond the edge of a contact the gel is stretched over the edge and
  decays smoothly to rest without touching the object. Its indentation there bends the way a
  free membrane does, convexly (positive Laplacian), while gel pressed onto a convex object
  follows the object and bends concavely or not at all. For a flat face with a sharp edge the
  predicted heightmap is a smoothed step whose inflection lies at the edge, so dropping the
  convex pixels cuts the mask at the true contact edge (:func:`membrane_skirt`).
* *Unobserved depth.* A camera-based sensor measures slope; heights are integrated from the
  undeformed gel. Where the true slope exceeds what the shape model reproduces (a cliff: the
  gel over a sharp edge), the integration misses part of the step and everything beyond it
  sits too shallow (0.3 mm on a 1 mm press for the bundled gelslim model), though its outline is
  right. :func:`depth_observed` keeps the pixels reachable from the undeformed gel through
  slopes below the model's saturation.

Shape fits use the contact pixels (not skirt) for *where* the surface stops and, among them,
those with observed depth for *where* the surface lies (:func:`tactojax.mapping.shape_fit_clouds`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from tactojax.geometry import heightmap_gradient

SKIRT_CURVATURE_PER_MM = 0.25
"""Laplacian of the indentation (1/mm) above which a contact pixel is membrane skirt. The skirt
beside a 1 mm cliff bends by about 1/mm; a 25 mm cylinder pressed 1 mm by -0.04/mm; the
tolerance leaves room for the gentle convex rim where a curved contact starts."""

SATURATION_SLOPE = 0.5
"""Slope (mm/mm, about 27 degrees) from which a predicted slope may be saturated. Measured for the
bundled gelslim shape model on the simulated Table II maps: predicted slopes follow the true
ones up to about 0.5 (true 0.4-0.5: predicted median 0.42), above it they stop growing (true 1-2:
predicted 0.7-0.8), so a predicted slope of 0.5 or more may hide a cliff."""

REST_DEPTH_MM = 0.02
"""Indentation below which the gel counts as undeformed (the start of the height integration)."""


def membrane_skirt(
    heightmap: Float[Array, "H W"],
    mm_per_px: float,
    *,
    curvature_per_mm: float = SKIRT_CURVATURE_PER_MM,
) -> Bool[Array, "H W"]:
    """Pixels where the gel bends like a free membrane (convexly): skirt, not contact.

    Args:
        heightmap: (H, W) indentation depth, mm.
        mm_per_px: pixel pitch, mm.
        curvature_per_mm: Laplacian of the indentation above which a pixel is skirt, 1/mm.

    Returns:
        (H, W) bool, True on the skirt. Five-point Laplacian; across the image border the
        heightmap is extended linearly (no curvature there: a replicated border would bend a
        slope that the border cuts into a false concave kink).
    """
    rows = jnp.concatenate([2 * heightmap[:1] - heightmap[1:2], heightmap,
                            2 * heightmap[-1:] - heightmap[-2:-1]], axis=0)
    padded = jnp.concatenate([2 * rows[:, :1] - rows[:, 1:2], rows, 2 * rows[:, -1:] - rows[:, -2:-1]], axis=1)
    laplacian = (padded[2:, 1:-1] + padded[:-2, 1:-1] + padded[1:-1, 2:] + padded[1:-1, :-2]
                 - 4.0 * heightmap) / mm_per_px**2
    return laplacian > curvature_per_mm


def depth_observed(
    heightmap: Float[Array, "H W"],
    mm_per_px: float,
    *,
    max_slope: float = SATURATION_SLOPE,
    rest_depth_mm: float = REST_DEPTH_MM,
) -> Bool[Array, "H W"]:
    """Pixels whose height is integrated from the undeformed gel through unsaturated slopes.

    A flood fill (8-connected) from the pixels at rest (indentation below ``rest_depth_mm``)
    through the pixels whose slope is below ``max_slope``: a region reached only across a steeper
    band (a cliff) is left out, since its depth misses the part of the cliff the model could
    not see.

    Args:
        heightmap: (H, W) indentation depth, mm.
        mm_per_px: pixel pitch, mm.
        max_slope: slope (mm/mm) from which predicted slopes may be saturated.
        rest_depth_mm: indentation at rest, mm.

    Returns:
        (H, W) bool: True where the depth is observed (rest pixels included).
    """
    slope = jnp.linalg.norm(heightmap_gradient(heightmap, mm_per_px), axis=-1)
    passable = slope < max_slope
    start = passable & (heightmap < rest_depth_mm)

    def grow(reached):
        around = jax.lax.reduce_window(reached.astype(jnp.float32), -jnp.inf, jax.lax.max,
                                       (3, 3), (1, 1), "SAME")
        return passable & (around > 0.0)

    def keep_going(state):
        _, changed, step = state
        return changed & (step < heightmap.size)

    def step(state):
        reached, _, count = state
        grown = reached
        for _ in range(8):  # a few steps per test of convergence
            grown = grow(grown)
        return grown, jnp.any(grown != reached), count + 8

    reached, _, _ = jax.lax.while_loop(keep_going, step, (start, jnp.asarray(True), jnp.asarray(0)))
    return reached
