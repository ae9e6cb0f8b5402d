"""How likely a touch is at a pose: its contact and its no-contact against the map's surface.

A touch is summarised by fixed-size evidence (:func:`~tactojax.localize._points.touch_evidence`): points where the gel
felt the object (x, y, -h) and points of the gel plane where it felt nothing (x, y, 0), both
in its sensor frame. At a pose hypothesis, both are placed in the object frame and read in the
whole map's signed-distance grid (:class:`~tactojax.localize.MapSurface`), point by point:

- a contact point where the surface is known: a robust Gaussian on its signed distance to
  the surface, ``log((1 - outlier) N(d; 0, sigma) + outlier / range)``;
- a contact point where the map knows no surface: ``log(1 / range)`` (the map says nothing);
- a no-contact point of the gel plane that lies inside the object deeper than ``margin_mm``
  (the object would have pressed the gel there): a violation, ``log(violation)``. This is the
  paper's "negative information" (its section VIII): it tells a patch from the same patch slid
  along an edge.

The sum over points is far too confident as it stands (neighbouring pixels' errors are not
independent): the belief scales it by a temperature fit on the map's own touches
(:class:`~tactojax.localize.BeliefCalibration`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Float

from tactojax.localize._correspondences import matvec
from tactojax.localize._points import TouchEvidence
from tactojax.localize._surface import MapSurface


@dataclass(frozen=True)
class LikelihoodSettings:
    """Noise model of a touch against the map (static)."""

    sigma_mm: float = 0.25
    """Standard deviation of a contact point's distance to the mapped surface, mm."""
    outlier: float = 0.1
    """Share of contact points that fit nowhere (mis-predicted heights, unmapped detail)."""
    range_mm: float = 10.0
    """Depth range of an outlier or of a point over unknown surface (uniform density), mm."""
    margin_mm: float = 0.3
    """A surface must press a gel deeper than this to count against a no-contact pixel, mm."""
    interpolate: bool = True
    """Read the surface trilinearly (False: the nearest grid cell, 8x fewer reads, for screening)."""
    violation: float = 0.05
    """Probability of a no-contact pixel where the map's surface presses the gel (or of
    contact in space the map saw free)."""


def point_log_likelihoods(
    surface: MapSurface,
    T_object_sensor: jaxlie.SE3,
    evidence: TouchEvidence,
    settings: LikelihoodSettings = LikelihoodSettings(),
) -> tuple[Float[Array, "P"], Float[Array, "F"]]:
    """Untempered log-likelihood of every contact and no-contact point of a touch at a pose.

    Args:
        surface: the map's surface.
        T_object_sensor: the touch's sensor pose hypothesis in the object frame, mm.
        evidence: the touch.
        settings: noise model.

    Returns:
        (P,) contact and (F,) no-contact log-likelihoods (0 for invalid points).
    """
    rotation, translation = T_object_sensor.rotation().as_matrix(), T_object_sensor.translation()
    count = evidence.contact.shape[0]
    points = matvec(rotation, jnp.concatenate([evidence.contact, evidence.free])) + translation
    distance, known = surface.signed_distance(points, interpolate=settings.interpolate)
    sigma, uniform = settings.sigma_mm, 1.0 / settings.range_mm
    gauss = jnp.exp(-0.5 * (distance[:count] / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))
    fit = jnp.log((1 - settings.outlier) * gauss + settings.outlier * uniform)
    contact_ll = jnp.where(known[:count], fit, math.log(uniform))
    pressed = known[count:] & (distance[count:] < -settings.margin_mm)
    free_ll = jnp.where(pressed, math.log(settings.violation), math.log1p(-settings.violation))
    return (jnp.where(evidence.contact_valid, contact_ll, 0.0), jnp.where(evidence.free_valid, free_ll, 0.0))


def log_likelihood(
    surface: MapSurface,
    T_object_sensor: jaxlie.SE3,
    evidence: TouchEvidence,
    settings: LikelihoodSettings = LikelihoodSettings(),
) -> Float[Array, ""]:
    """Log-likelihood of a touch at ``T_object_sensor``, the sum over its points (untempered;
    higher is better)."""
    contact_ll, free_ll = point_log_likelihoods(surface, T_object_sensor, evidence, settings)
    return jnp.sum(contact_ll) + jnp.sum(free_ll)


def align_depth(
    surface: MapSurface,
    T_object_sensor: jaxlie.SE3,
    evidence: TouchEvidence,
    *,
    iterations: int = 2,
    max_offset_mm: float = 3.0,
    interpolate: bool = True,
) -> jaxlie.SE3:
    """The pose moved along its gel normal (the sensor's z) so that the touch's contact meets
    the surface.

    A shifted or turned hypothesis is generally too deep or too shallow; the depth offset is
    the one degree of freedom a contact patch pins down at once. The first iteration moves by
    the mean signed distance of the contact points whose surface is known within
    ``max_offset_mm``; each later one by the mean of those within ``max_offset_mm / 3`` of the
    previous estimate (a trimmed mean: no sort, cheap for thousands of candidates).
    ``interpolate``: read the surface trilinearly (False: the nearest cell, as screening reads
    it; the mean offset of many points is then off by a few hundredths of a millimetre).
    """
    def step(carry, width):
        T, previous = carry
        rotation, translation = T.rotation().as_matrix(), T.translation()
        distance, known = surface.signed_distance(matvec(rotation, evidence.contact) + translation,
                                                  interpolate=interpolate)
        use = evidence.contact_valid & known & (jnp.abs(distance - previous) <= width)
        offset = jnp.sum(jnp.where(use, distance - previous, 0.0)) / jnp.maximum(jnp.sum(use), 1)
        # Moving the sensor by +offset along its z carries the contact that far into the object.
        T = T @ jaxlie.SE3.from_translation(jnp.array([0.0, 0.0, 1.0]) * offset)
        return (T, jnp.zeros_like(offset)), None

    widths = max_offset_mm / 3.0 ** jnp.arange(iterations, dtype=jnp.float32)
    (T, _), _ = jax.lax.scan(step, (T_object_sensor, jnp.float32(0.0)), widths)
    return T
