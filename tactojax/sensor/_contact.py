"""Contact model: object distances seen from the gel -> indentation heightmap and mask.

A jaw closes along the sensor's +z axis. Every pixel's ray (from the undeformed gel surface,
along +z) meets the object at some distance. The gel touches first where that distance is
smallest; the jaw then presses on by the penetration depth, so a rigid object would indent the
gel by ``max(0, travel - distance)`` with ``travel = min(distance) + depth``.

Elastic smoothing. A real elastomer cannot follow the object exactly where the object leaves
the gel: around the contact patch it forms a smooth skirt (the membrane is stretched over the
edge), and it bridges narrow cavities instead of filling them. We model the gel surface as

    h_gel = max(h_rigid, G_sigma * h_rigid),

the rigid indentation lifted by its own Gaussian-smoothed version (sigma ~ a fraction of the
gel thickness). The gel is never shallower than the rigid indentation (the object cannot be
penetrated). Well inside the contact patch (more than about 2 sigma from its edge) h_gel equals
the rigid indentation; outside it, and over cavities narrower than a few sigma, the gel takes
the smooth envelope. In a band about 2 sigma wide just inside the patch edge the envelope is
the deeper of the two, so there the membrane sags slightly below the object's surface (by up
to ~0.1 mm for a 1 mm press on a 6 mm sphere), as a membrane stretched over an edge does.
The contact mask is the geometric contact patch, where the rigid object reaches into the
undeformed gel (h_rigid > 0), including that band. This is a geometric stand-in for an elastic
half-space solution, documented as such; it keeps every output differentiable.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from tactojax import _struct as struct
from tactojax.sensor._smoothing import gaussian_blur
from tactojax.sensor._spec import SensorSpec

MIN_INDENTATION_MM = 1e-3
"""Indentation below which a pixel does not count as in contact (numerical floor), mm."""


@struct.dataclass
class Contact:
    """The result of pressing one sensor onto an object."""

    heightmap: Float[Array, "H W"]
    """Gel surface indentation after elastic smoothing, mm (>= 0)."""
    rigid_heightmap: Float[Array, "H W"]
    """Indentation a perfectly conforming gel would have (the object's shape), mm (>= 0)."""
    mask: Bool[Array, "H W"]
    """Geometric contact patch: where the object reaches into the undeformed gel (h_rigid > 0)."""
    travel: Float[Array, ""]
    """How far the jaw moved from its start along sensor +z, mm."""
    touched: Bool[Array, ""]
    """Whether any ray met the object (False: nothing to press, all outputs zero)."""


def press(
    spec: SensorSpec,
    distances: Float[Array, "H W"],
    hit: Bool[Array, "H W"],
    depth_mm: Float[Array, ""],
) -> Contact:
    """Press the gel onto an object given the per-pixel distances to it.

    Args:
        spec: the sensor (static sizes, smoothing).
        distances: (H, W) distance along sensor +z from the undeformed gel (at the jaw's start)
            to the object, mm. Ignored where ``hit`` is False.
        hit: (H, W) whether each pixel's ray meets the object.
        depth_mm: penetration depth past first contact, mm.

    Returns:
        :class:`Contact`.
    """
    touched = jnp.any(hit)
    first_contact = jnp.min(jnp.where(hit, distances, jnp.inf))
    first_contact = jnp.where(touched, first_contact, 0.0)
    travel = first_contact + depth_mm
    rigid = jnp.where(hit, jnp.maximum(travel - distances, 0.0), 0.0)
    rigid = jnp.where(touched, rigid, 0.0)
    return Contact(
        heightmap=gel_surface(spec, rigid),
        rigid_heightmap=rigid,
        mask=rigid > MIN_INDENTATION_MM,
        travel=travel,
        touched=touched,
    )


def gel_surface(spec: SensorSpec, rigid_heightmap: Float[Array, "H W"]) -> Float[Array, "H W"]:
    """Elastic smoothing of a rigid indentation (see the module docstring), mm."""
    sigma_px = spec.gel_smoothing_mm / spec.mm_per_px
    return jnp.maximum(rigid_heightmap, gaussian_blur(rigid_heightmap, sigma_px))
