"""Multi-start registration: ICP from several retrieved poses at once (vmap), keep the best."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Bool, Float, Int

from tactojax.localize._icp import IcpSettings, icp
from tactojax.localize._map import LocalizationMap
from tactojax.localize._pose import PoseEstimate

OVERLAP_WEIGHT_MM = 1.0
"""Selection cost of a start: score (mm) + this x (1 - overlap)."""


def selection_cost(estimate: PoseEstimate, *, overlap_weight_mm: float = OVERLAP_WEIGHT_MM) -> Float[Array, "..."]:
    """Cost used to pick among registrations: robust residual RMS plus a penalty for points
    left without a match (mm). Lower is better."""
    return estimate.score + overlap_weight_mm * (1.0 - estimate.overlap)


def register_multistart(
    view: LocalizationMap,
    candidates: Int[Array, "N"],
    candidate_valid: Bool[Array, "N"],
    points: Float[Array, "P 3"],
    points_valid: Bool[Array, "P"],
    starts: Int[Array, "S"],
    start_valid: Bool[Array, "S"],
    settings: IcpSettings = IcpSettings(),
    *,
    overlap_weight_mm: float = OVERLAP_WEIGHT_MM,
) -> tuple[PoseEstimate, PoseEstimate]:
    """ICP from the poses of several map imprints against the same candidates; pick the best.

    Args:
        view: the map.
        candidates: (N,) imprints registered against (their union is the target surface).
        candidate_valid: (N,) which candidates are real.
        points: (P, 3) query points, query sensor frame, mm.
        points_valid: (P,) which points are real.
        starts: (S,) imprints whose poses start the S registrations.
        start_valid: (S,) which starts are real.
        settings: ICP parameters.
        overlap_weight_mm: see :func:`selection_cost`.

    Returns:
        the chosen estimate (``imprint_index`` = its start imprint), and all S estimates.
    """
    T_starts = jax.tree.map(lambda x: x[starts], view.T_object_sensor)
    run = jax.vmap(icp, in_axes=(None, None, None, None, None, 0, None))
    estimates = run(view, candidates, candidate_valid, points, points_valid, T_starts, settings)
    estimates = estimates.replace(imprint_index=starts.astype(jnp.int32))
    cost = selection_cost(estimates, overlap_weight_mm=overlap_weight_mm)
    # Converged starts first, then the lowest cost; invalid starts never win if any is valid.
    rank = jnp.where(start_valid, cost + jnp.where(estimates.converged, 0.0, 1e3), jnp.inf)
    best = jnp.argmin(rank)
    chosen = jax.tree.map(lambda x: x[best], estimates)
    return chosen, estimates


def start_pose(view: LocalizationMap, index: Int[Array, ""]) -> jaxlie.SE3:
    """The stored pose of imprint ``index``."""
    return jax.tree.map(lambda x: x[index], view.T_object_sensor)
