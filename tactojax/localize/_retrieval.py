"""Closest tactile imprints by cosine similarity of features (paper section VI, CTI)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from tactojax.localize._compile import top_level_jit

MAX_OPENING_DIFFERENCE_MM = 2.0
"""CTI compares only imprints whose gripper opening differs by less than this (paper VI)."""


def cosine_similarities(
    features: Float[Array, "K F"], query_feature: Float[Array, "F"]
) -> Float[Array, "K"]:
    """Cosine similarity of a query feature vector to every row of ``features``.

    A zero vector has similarity 0 to everything (never NaN).

    Args:
        features: (K, F) feature vectors of the map's imprints.
        query_feature: (F,) feature vector of the query imprint.

    Returns:
        (K,) similarities in [-1, 1].
    """
    eps = 1e-12
    rows = features / jnp.maximum(jnp.linalg.norm(features, axis=-1, keepdims=True), eps)
    query = query_feature / jnp.maximum(jnp.linalg.norm(query_feature), eps)
    return rows @ query


@functools.partial(top_level_jit, static_argnames=("n",))
def closest_imprints(
    features: Float[Array, "K F"],
    openings: Float[Array, "K"],
    imprint_valid: Bool[Array, "K"],
    query_feature: Float[Array, "F"],
    query_opening: Float[Array, ""],
    n: int,
    *,
    max_opening_difference_mm: float | Float[Array, ""] = MAX_OPENING_DIFFERENCE_MM,
    exclude: int | Int[Array, ""] = -1,
) -> tuple[Int[Array, "n"], Float[Array, "n"], Bool[Array, "n"]]:
    """The ``n`` imprints most similar to a query, among those with a similar gripper opening.

    Paper section VI (CTI): cosine similarity of feature vectors, considering only imprints
    whose opening differs from the query's by less than ``max_opening_difference_mm``.

    Args:
        features: (K, F) map features.
        openings: (K,) map gripper openings, mm.
        imprint_valid: (K,) which map imprints may be retrieved.
        query_feature: (F,) the query's features.
        query_opening: the query's gripper opening, mm.
        n: how many imprints to return (static; a map with fewer than ``n`` imprints pads the
            result with invalid entries).
        max_opening_difference_mm: opening filter, mm (``inf`` disables it).
        exclude: an imprint index never returned (leave-one-out), -1 for none.

    Returns:
        indices (n,) most similar first, their similarities (n,), and valid (n,): False where
        fewer than ``n`` imprints pass the filters (those indices are arbitrary).
    """
    similarities = cosine_similarities(features, query_feature)
    return rank_imprints(similarities, openings, imprint_valid, query_opening, n,
                         max_opening_difference_mm=max_opening_difference_mm, exclude=exclude)


def rank_imprints(
    similarities: Float[Array, "K"],
    openings: Float[Array, "K"],
    imprint_valid: Bool[Array, "K"],
    query_opening: Float[Array, ""],
    n: int,
    *,
    max_opening_difference_mm: float | Float[Array, ""] = MAX_OPENING_DIFFERENCE_MM,
    exclude: int | Int[Array, ""] = -1,
) -> tuple[Int[Array, "n"], Float[Array, "n"], Bool[Array, "n"]]:
    """:func:`closest_imprints` from precomputed similarities (K,)."""
    index = jnp.arange(similarities.shape[0])
    eligible = (imprint_valid
                & (jnp.abs(openings - query_opening) < max_opening_difference_mm)
                & (index != exclude))
    _, indices = jax.lax.top_k(jnp.where(eligible, similarities, -jnp.inf), min(n, similarities.shape[0]))
    valid = eligible[indices]
    if indices.shape[0] < n:  # a small map: pad with invalid copies of the first entry
        pad = n - indices.shape[0]
        indices = jnp.concatenate([indices, jnp.zeros(pad, indices.dtype)])
        valid = jnp.concatenate([valid, jnp.zeros(pad, bool)])
    return indices, similarities[indices], valid
