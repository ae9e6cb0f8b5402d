"""Retrieve, search, register, verify: our localization beyond the paper's CTI-ICP-N.

CTI-ICP-N starts ICP at the single closest imprint and registers against the N most similar
ones. Two things limit it: the closest imprint is often not the right place (similar imprints
recur along an object), and point-to-plane ICP cannot slide a patch along a flat face or an
edge, so a start 10 mm off (the mapping grid) stays 10 mm off. Here:

1. retrieval keeps the N most similar imprints (CTI's metric and opening filter);
2. every retrieved imprint spawns hypotheses: its pose shifted in its sensor plane on a small
   grid, each checked against the imprint's *spatial* neighbours in the map (their contact
   centres are nearest), which cover the surface around it whatever their similarity;
3. hypotheses are ranked by :func:`consistency` (agreement minus free-space violations, both
   ways), the best few are refined by ICP against their neighbours (vmapped);
4. every refined pose is checked again against the map around the place it claims (the
   imprints nearest to the placed query), so that all are judged on the same evidence; the
   most consistent wins, ties going to the more similar retrieved imprint.

Every step has fixed shapes: one compilation per map size and settings.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Bool, Float, Int

from tactojax.localize._consistency import consistency
from tactojax.localize._correspondences import valid_centroid
from tactojax.localize._icp import IcpSettings, icp
from tactojax.localize._map import LocalizationMap
from tactojax.localize._pose import PoseEstimate


@dataclass(frozen=True)
class SearchSettings:
    """Hypothesis search parameters (static)."""

    neighbours: int = 6
    """Spatial neighbours (the start imprint included) that each hypothesis is checked and registered against."""
    shift_mm: float = 5.0
    """Step of the in-plane shift grid, mm."""
    shift_steps: int = 2
    """Shifts run from -steps to +steps along x and y: (2 steps + 1)^2 per retrieved imprint."""
    refine: int = 1
    """Hypotheses refined by ICP (2 costs 5 ms more per touch and measured no better on the
    simulated maps: the coarse ranking already decides)."""
    scoring_points: int = 32
    """Query points used to rank the unrefined hypotheses (query -> map evidence only)."""
    coarse_tolerance_mm: float = 1.5
    """Agreement tolerance before refinement (depth is not yet aligned), mm."""
    coarse_margin_mm: float = 1.0
    """Violation margin before refinement, mm."""
    verify_neighbours: int = 10
    """Imprints around each refined pose that it is finally checked against."""
    violation_weight: float = 10.0
    """Weight of free-space violations against agreement in the final check."""
    similarity_weight: float = 0.1
    """Weight of the retrieved imprint's feature similarity in the final check."""

    @property
    def shifts(self) -> Float[Array, "S 3"]:
        """(S, 3) in-plane shifts of the grid, sensor frame, mm (zero first)."""
        steps = jnp.arange(-self.shift_steps, self.shift_steps + 1, dtype=jnp.float32) * self.shift_mm
        x, y = jnp.meshgrid(steps, steps, indexing="xy")
        shifts = jnp.stack([x.ravel(), y.ravel(), jnp.zeros(x.size)], axis=-1)
        order = jnp.argsort(jnp.linalg.norm(shifts, axis=-1), stable=True)
        return shifts[order]


def imprints_near(
    view: LocalizationMap, point: Float[Array, "3"], n: int, available: Bool[Array, "K"]
) -> tuple[Int[Array, "n"], Bool[Array, "n"]]:
    """The n available imprints whose contact centres are nearest to ``point`` (object frame)."""
    distance = jnp.linalg.norm(view.centres - point, axis=-1)
    _, nearest = jax.lax.top_k(jnp.where(available, -distance, -jnp.inf), n)
    return nearest, available[nearest]


def spatial_neighbours(
    view: LocalizationMap, index: Int[Array, ""], n: int, available: Bool[Array, "K"]
) -> tuple[Int[Array, "n"], Bool[Array, "n"]]:
    """The n available imprints whose contact centres are nearest to imprint ``index``'s.

    ``index`` itself comes first when available (distance 0).
    """
    return imprints_near(view, view.centres[index], n, available)


def verification_score(
    view: LocalizationMap,
    query_heightmap: Float[Array, "H W"],
    query_mask: Bool[Array, "H W"],
    points: Float[Array, "P 3"],
    points_valid: Bool[Array, "P"],
    T_object_sensor: jaxlie.SE3,
    available: Bool[Array, "K"],
    settings: SearchSettings = SearchSettings(),
) -> Float[Array, ""]:
    """How well a pose of the query agrees with the map around the place it claims (higher is better).

    The final check of :func:`search_and_register` (without its feature-similarity tie-break):
    the query placed at ``T_object_sensor`` against the ``settings.verify_neighbours`` available
    imprints nearest to it, agreement minus ``settings.violation_weight`` times the free-space
    violations in both directions (:func:`consistency`). At most 1 (every point on the surface,
    none in free space).

    Args:
        view: the map.
        query_heightmap, query_mask: (H, W) the query imprint.
        points: (P, 3) query points, query sensor frame, mm; points_valid (P,).
        T_object_sensor: the pose to check.
        available: (K,) imprints that may be checked against (the map minus any held-out one).
        settings: search parameters.
    """
    centroid = valid_centroid(points, points_valid)
    around, around_valid = imprints_near(view, T_object_sensor @ centroid, settings.verify_neighbours, available)
    check = consistency(view, around, around_valid, query_heightmap, query_mask, points, points_valid, T_object_sensor)
    return check.agreement - settings.violation_weight * (check.violation + check.reverse_violation)


def search_and_register(
    view: LocalizationMap,
    query_heightmap: Float[Array, "H W"],
    query_mask: Bool[Array, "H W"],
    points: Float[Array, "P 3"],
    points_valid: Bool[Array, "P"],
    retrieved: Int[Array, "M"],
    retrieved_similarity: Float[Array, "M"],
    retrieved_valid: Bool[Array, "M"],
    available: Bool[Array, "K"],
    icp_settings: IcpSettings = IcpSettings(),
    settings: SearchSettings = SearchSettings(),
) -> PoseEstimate:
    """Localize a query from its retrieved imprints (see the module docstring).

    Args:
        view: the map.
        query_heightmap, query_mask: (H, W) the query imprint.
        points: (P, 3) query points, query sensor frame, mm; points_valid (P,).
        retrieved: (M,) retrieved imprints, most similar first; their feature similarities
            (M,) and retrieved_valid (M,).
        available: (K,) imprints that may serve as neighbours (the map minus any held-out one).
        icp_settings: ICP parameters for the refinement.
        settings: search parameters.

    Returns:
        the best refined estimate (``imprint_index``: the retrieved imprint it came from).
    """
    shifts = settings.shifts
    count_shifts = shifts.shape[0]
    neighbours, neighbours_valid = jax.vmap(
        lambda index: spatial_neighbours(view, index, settings.neighbours, available))(retrieved)
    neighbours_valid = neighbours_valid & retrieved_valid[:, None]
    T_retrieved = jax.tree.map(lambda x: x[retrieved], view.T_object_sensor)

    # Hypotheses (M * S): every retrieved pose shifted in its own sensor plane.
    def shifted(T):
        return jax.vmap(lambda shift: T @ jaxlie.SE3.from_translation(shift))(shifts)
    T_hypotheses = jax.tree.map(lambda x: x.reshape(-1, *x.shape[2:]), jax.vmap(shifted)(T_retrieved))
    source = jnp.repeat(jnp.arange(retrieved.shape[0]), count_shifts)
    few, few_valid = points[:settings.scoring_points], points_valid[:settings.scoring_points]

    def coarse_score(T, m):
        check = consistency(view, neighbours[m], neighbours_valid[m], query_heightmap, query_mask, few, few_valid,
                            T, tolerance_mm=settings.coarse_tolerance_mm, margin_mm=settings.coarse_margin_mm,
                            reverse=False)
        return jnp.where(retrieved_valid[m], check.score(), -jnp.inf)

    scores = jax.vmap(coarse_score)(T_hypotheses, source)
    _, best = jax.lax.top_k(scores, settings.refine)
    chosen = source[best]

    def refine(T_start, m):
        estimate = icp(view, neighbours[m], neighbours_valid[m], points, points_valid, T_start, icp_settings)
        score = (verification_score(view, query_heightmap, query_mask, points, points_valid, estimate.T_object_sensor,
                                    available, settings)
                 + settings.similarity_weight * retrieved_similarity[m])
        return estimate.replace(imprint_index=retrieved[m].astype(jnp.int32)), score

    T_starts = jax.tree.map(lambda x: x[best], T_hypotheses)
    estimates, final_scores = jax.vmap(refine)(T_starts, chosen)
    final_scores = jnp.where(retrieved_valid[chosen] & jnp.isfinite(scores[best]), final_scores, -jnp.inf)
    winner = jnp.argmax(final_scores)
    return jax.tree.map(lambda x: x[winner], estimates)
