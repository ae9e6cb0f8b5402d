"""Does a pose hypothesis agree with what the sensors felt? (verification of registrations)

Point-to-plane residuals only see where surfaces overlap; a patch slid along a flat face or a
straight edge fits as well as the right one. The contact masks carry the missing evidence: a
sensor that felt *nothing* at a pixel says that the object does not reach into its gel there.
A hypothesis for the query pose is scored in both directions:

- query points placed in the map: matched (on a candidate's contact within ``tolerance_mm``)
  or violating (inside a candidate's image, where it felt nothing, deeper than
  ``margin_mm`` into its gel);
- candidate points placed in the query's sensor frame: matched against the query heightmap,
  or violating where the query felt nothing.

Only clear non-contact counts as evidence: a pixel outside the mask whose height is above
``free_height_mm`` (a flat contact the image barely observes) is not free space.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
from flax import struct
from jaxtyping import Array, Bool, Float, Int

from tactojax.localize._correspondences import candidate_poses, pixel_lookup, transform_points
from tactojax.localize._map import LocalizationMap

TOLERANCE_MM = 0.5
"""A point within this of a contact surface agrees with it, mm."""
MARGIN_MM = 0.3
"""A point deeper than this into a gel that felt nothing violates it, mm."""
FREE_HEIGHT_MM = 0.08
"""Outside the mask, a pixel with less indentation than this is free space, mm."""
VIOLATION_WEIGHT = 2.0
"""Weight of the violations against the agreements in :meth:`Consistency.score`."""


@struct.dataclass
class Consistency:
    """Agreement and violation fractions of one pose hypothesis (see the module docstring)."""

    agreement: Float[Array, ""]
    """Fraction of the query points on a candidate's contact surface."""
    violation: Float[Array, ""]
    """Fraction of the query points inside a candidate's free space."""
    reverse_agreement: Float[Array, ""]
    """Fraction of the candidate points inside the query's image that are on its contact surface."""
    reverse_violation: Float[Array, ""]
    """Fraction of the candidate points inside the query's image that are in its free space."""

    def score(self, violation_weight: float = VIOLATION_WEIGHT) -> Float[Array, ""]:
        """Higher is better: agreements minus weighted violations (both directions)."""
        return (self.agreement + self.reverse_agreement
                - violation_weight * (self.violation + self.reverse_violation))


def _evidence(height, slope, in_contact, inside, z, valid, tolerance_mm, margin_mm, free_height_mm):
    residual = (z + height) * jax.lax.rsqrt(1.0 + jnp.sum(slope**2, axis=-1))
    agree = valid & in_contact & (jnp.abs(residual) <= tolerance_mm)
    violate = valid & inside & ~in_contact & (height < free_height_mm) & (z < -margin_mm)
    return agree, violate


def consistency(
    view: LocalizationMap,
    candidates: Int[Array, "N"],
    candidate_valid: Bool[Array, "N"],
    query_heightmap: Float[Array, "H W"],
    query_mask: Bool[Array, "H W"],
    points: Float[Array, "P 3"],
    points_valid: Bool[Array, "P"],
    T_object_sensor: jaxlie.SE3,
    *,
    tolerance_mm: float = TOLERANCE_MM,
    margin_mm: float = MARGIN_MM,
    free_height_mm: float = FREE_HEIGHT_MM,
    reverse: bool = True,
) -> Consistency:
    """Agreement and violation of a query pose hypothesis with N candidate imprints.

    Args:
        view: the map (its ``points`` are the candidate points).
        candidates: (N,) imprints to check against; candidate_valid (N,).
        query_heightmap, query_mask: (H, W) the query's heightmap (mm) and contact mask.
        points: (P, 3) query points, query sensor frame, mm; points_valid (P,).
        T_object_sensor: the hypothesis (query sensor pose in the object frame).
        tolerance_mm, margin_mm, free_height_mm: see the module constants.
        reverse: also place the candidates' points in the query's frame (static; without it
            the reverse fractions are 0, for a cheaper check).

    Returns:
        :class:`Consistency`.
    """
    # Query points in every candidate's sensor frame: (N, P, 3).
    T_sensor_candidate = candidate_poses(view, candidates)
    moved = transform_points(T_object_sensor, points)
    p_sensor = (jnp.einsum("nij,pj->npi", T_sensor_candidate.rotation().as_matrix(), moved)
                + T_sensor_candidate.translation()[:, None])
    imprint = jnp.broadcast_to(candidates[:, None], p_sensor.shape[:2])
    lookup = pixel_lookup(view.heightmaps, view.masks, imprint, p_sensor, view.mm_per_px)
    valid = candidate_valid[:, None] & points_valid[None, :]
    agree, violate = _evidence(*lookup, p_sensor[..., 2], valid, tolerance_mm, margin_mm, free_height_mm)
    count = jnp.maximum(jnp.sum(points_valid), 1)
    agreement = jnp.sum(jnp.any(agree, axis=0)) / count
    violation = jnp.sum(jnp.any(violate, axis=0) & ~jnp.any(agree, axis=0)) / count

    if not reverse:
        zero = jnp.zeros_like(agreement)
        return Consistency(agreement=agreement, violation=violation, reverse_agreement=zero, reverse_violation=zero)
    # Candidate points in the query's sensor frame: (N, Q, 3).
    p_query = transform_points(T_object_sensor.inverse(), view.points[candidates])
    lookup = pixel_lookup(query_heightmap[None], query_mask[None], jnp.zeros(p_query.shape[:2], jnp.int32),
                          p_query, view.mm_per_px)
    valid = candidate_valid[:, None] & view.points_valid[candidates]
    agree, violate = _evidence(*lookup, p_query[..., 2], valid, tolerance_mm, margin_mm, free_height_mm)
    seen = jnp.maximum(jnp.sum(valid & lookup[3]), 1)
    return Consistency(agreement=agreement, violation=violation,
                       reverse_agreement=jnp.sum(agree) / seen, reverse_violation=jnp.sum(violate) / seen)
