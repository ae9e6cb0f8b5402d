"""Exact ray casting against analytic solids (pure JAX, differentiable)."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from tactojax import _struct as struct
from tactojax.objects._primitives import Solid


@struct.dataclass
class RayHits:
    """First intersections of a batch of rays with a solid."""

    distance: Float[Array, "*rays"]
    """Distance along each (unit) ray to its first hit, mm; ``max_distance`` where it missed."""
    hit: Bool[Array, "*rays"]
    """Whether the ray met the surface within ``max_distance``."""
    starts_inside: Bool[Array, "*rays"]
    """Whether the ray's origin is already inside the solid (a collision)."""


def raycast(
    solid: Solid,
    origins: Float[Array, "*rays 3"],
    directions: Float[Array, "*rays 3"],
    *,
    max_distance: float,
) -> RayHits:
    """First hit of each ray ``o + t d`` (t >= 0) with ``solid``, in closed form.

    Exact (no marching) and differentiable in the rays and the solid's parameters where the
    hit surface is smooth.

    Args:
        solid: an analytic solid (``ray_interval``).
        origins: (*rays, 3) ray origins, mm, in the solid's frame.
        directions: (*rays, 3) unit directions.
        max_distance: how far to look, mm.

    Returns:
        :class:`RayHits` with the rays' batch shape.
    """
    enter, exit_ = solid.ray_interval(origins, directions)
    nonempty = enter <= exit_
    starts_inside = nonempty & (enter <= 0.0)
    hit = nonempty & (enter > 0.0) & (enter < max_distance)
    distance = jnp.where(hit, enter, max_distance)
    return RayHits(distance=distance, hit=hit, starts_inside=starts_inside)
