"""Localization methods: the paper's RANDOM, CTI, CTI-ICP-N (section VI), and ours.

``localize`` is the one entry point: jitted, compiled once per map size and method, so a
control loop can call it for every touch. A method is named by a string:

- ``"random"``: the pose of a random stored imprint (the paper's baseline);
- ``"cti"``: the pose of the closest tactile imprint (cosine similarity of features, among
  imprints whose gripper opening differs by less than 2 mm);
- ``"cti-icp-N"``: ICP of the query cloud against the union of the N most similar imprints,
  started at the closest one (the paper's CTI-ICP-N);
- ``"cti-icp-multistart-N"``: the same ICP started from each of the N most similar imprints
  (vmapped), keeping the best fit by residual and overlap;
- ``"cti-search-N"`` (ours, :mod:`tactojax.localize._search`): hypotheses around each of the N
  most similar imprints, checked against their spatial neighbours for consistency with what
  both sensors felt, the best refined by ICP.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from tactojax.localize._icp import IcpSettings, fit_quality, icp
from tactojax.localize._map import LocalizationMap, Query, as_localization_map, canonical_query
from tactojax.localize._pose import PoseEstimate
from tactojax.localize._register import register_multistart, start_pose
from tactojax.localize._retrieval import MAX_OPENING_DIFFERENCE_MM, rank_imprints
from tactojax.localize._search import SearchSettings, search_and_register
from tactojax.mapping import TactileMap

POINTS_PER_QUERY = 128
"""Contact points sampled from a query heightmap for ICP."""

PAPER_METHODS = ("random", "cti", "cti-icp-1", "cti-icp-5")
"""The methods of the paper's Table III."""

_PATTERN = re.compile(r"^(random|cti|belief|cti-(icp|icp-multistart|search)-(\d+))$")


@dataclass(frozen=True)
class Method:
    """A parsed method name (static)."""

    kind: str
    """``"random"``, ``"cti"``, ``"cti-icp"``, ``"cti-icp-multistart"``, ``"cti-search"`` or
    ``"belief"`` (:mod:`tactojax.localize._belief`)."""
    n: int
    """Imprints retrieved (N); 1 for CTI, 0 for RANDOM."""

    @property
    def name(self) -> str:
        return self.kind if self.kind in ("random", "cti", "belief") else f"{self.kind}-{self.n}"


def parse_method(method: str | Method) -> Method:
    """Parse ``"random"``, ``"cti"``, ``"cti-icp-N"``, ``"cti-icp-multistart-N"`` or
    ``"cti-search-N"`` (N >= 1)."""
    if isinstance(method, Method):
        return method
    match = _PATTERN.match(method.strip().lower())
    if match is None or int(match.group(3) or 1) < 1:
        raise ValueError(f"unknown localization method {method!r}: use belief, random, cti, cti-icp-N, "
                         "cti-icp-multistart-N or cti-search-N with N >= 1")
    if match.group(1) in ("random", "cti", "belief"):
        return Method(match.group(1), 1 if match.group(1) == "cti" else 0)
    return Method(f"cti-{match.group(2)}", int(match.group(3)))


@functools.lru_cache(maxsize=8)
def pixel_priority(height_px: int, width_px: int, seed: int = 0) -> np.ndarray:
    """A fixed random order of the pixels (in [0, 1)): the same draw for every query."""
    order = np.random.default_rng(seed).permutation(height_px * width_px)
    return (order / (height_px * width_px)).astype(np.float32)


def draw_pixels(
    flat: Bool[Array, "N"], priority: np.ndarray, count: int
) -> tuple[Int[Array, "count"], Bool[Array, "count"]]:
    """``count`` pixels drawn uniformly without replacement where ``flat`` holds, by the fixed
    order ``priority`` (:func:`pixel_priority`), padded with pixels where it does not; and valid."""
    _, index = jax.lax.top_k(jnp.asarray(priority) + flat.astype(jnp.float32), count)
    return index, flat[index]


def query_points(
    query: Query, mm_per_px: float, count: int = POINTS_PER_QUERY
) -> tuple[Float[Array, "P 3"], Bool[Array, "P"]]:
    """``count`` contact points of a query (sensor frame, mm) drawn from its mask, and valid.

    A uniform draw without replacement among the contact pixels (padded with invalid points
    when there are fewer), by a fixed random order of the pixels: the same imprint always gives
    the same points (repeatable in a control loop; no random numbers to generate). Differentiable
    with respect to ``query.heightmap`` (the pixels are chosen from the mask).
    """
    height_px, width_px = query.heightmap.shape
    flat_mask = query.mask.reshape(-1)
    index, valid = draw_pixels(flat_mask, pixel_priority(height_px, width_px), count)
    row, col = index // width_px, index % width_px
    x = (col - (width_px - 1) / 2.0) * mm_per_px
    y = (row - (height_px - 1) / 2.0) * mm_per_px
    points = jnp.stack([x, y, -query.heightmap.reshape(-1)[index]], axis=-1)
    return points, valid


def random_estimate(key: PRNGKeyArray, view: LocalizationMap, exclude) -> PoseEstimate:
    """RANDOM: the pose of a uniformly drawn stored imprint (never ``exclude``)."""
    index = jnp.arange(len(view))
    eligible = view.imprint_valid & (index != exclude)
    choice = jax.random.categorical(key, jnp.where(eligible, 0.0, -jnp.inf))
    estimate = PoseEstimate.failed(start_pose(view, choice), choice)
    return estimate.replace(converged=jnp.any(eligible))


def estimate_pose(
    view: LocalizationMap,
    query: Query,
    points: Float[Array, "P 3"],
    points_valid: Bool[Array, "P"],
    indices: Int[Array, "N"],
    indices_valid: Bool[Array, "N"],
    method: Method,
    *,
    similarities: Float[Array, "N"] | None = None,
    settings: IcpSettings = IcpSettings(),
    search: SearchSettings = SearchSettings(),
    exclude: int | Int[Array, ""] = -1,
) -> PoseEstimate:
    """CTI, CTI-ICP-N, multi-start or search from the retrieved imprints (most similar first).

    Args:
        view: the map.
        query: the query imprint (the search method checks hypotheses against its mask).
        points: (P, 3) query points, sensor frame, mm; points_valid (P,).
        indices: (N,) retrieved imprints, most similar first; indices_valid (N,).
        method: a parsed non-random method (N = ``len(indices)``).
        similarities: (N,) their feature similarities (the search breaks ties with them;
            default: decreasing with the rank).
        settings: ICP parameters.
        search: search parameters (method ``cti-search-N``).
        exclude: an imprint never used (leave-one-out), -1 for none.

    Returns:
        the estimate; with no valid retrieved imprint, the identity pose, not converged.
    """
    any_valid = indices_valid[0]
    first = indices[0]
    T_first = start_pose(view, first)
    if method.kind == "cti":
        score, overlap, _ = fit_quality(view, indices[:1], indices_valid[:1], points, points_valid,
                                        T_first, settings)
        # Retrieval alone does not need contact, but a touch without any is no localization.
        estimate = PoseEstimate(T_object_sensor=T_first, score=score, overlap=overlap,
                                converged=any_valid & jnp.any(points_valid), iterations=jnp.int32(0),
                                imprint_index=first.astype(jnp.int32))
    elif method.kind == "cti-icp":
        estimate = icp(view, indices, indices_valid, points, points_valid, T_first, settings)
        estimate = estimate.replace(imprint_index=first.astype(jnp.int32))
    elif method.kind == "cti-icp-multistart":
        estimate, _ = register_multistart(view, indices, indices_valid, points, points_valid,
                                          indices, indices_valid, settings)
    elif method.kind == "cti-search":
        available = view.imprint_valid & (jnp.arange(len(view)) != exclude)
        if similarities is None:
            similarities = 1.0 - jnp.arange(indices.shape[0]) / indices.shape[0]
        estimate = search_and_register(view, query.heightmap, query.mask, points, points_valid, indices,
                                       similarities, indices_valid, available, settings, search)
    else:
        raise ValueError(f"estimate_pose does not handle method {method.name!r}")
    # No retrieved imprint: no estimate (identity pose, not converged).
    return jax.tree.map(lambda a, b: jnp.where(any_valid, a, b), estimate,
                        PoseEstimate.failed(jaxlie.SE3.identity(), -1))


def localize_query(
    key: PRNGKeyArray,
    view: LocalizationMap,
    query: Query,
    method: Method,
    *,
    settings: IcpSettings = IcpSettings(),
    search: SearchSettings = SearchSettings(),
    points_per_query: int = POINTS_PER_QUERY,
    max_opening_difference_mm: float | Float[Array, ""] = MAX_OPENING_DIFFERENCE_MM,
    exclude: int | Int[Array, ""] = -1,
) -> PoseEstimate:
    """:func:`localize` for one query without the jit (vmap it for batches)."""
    if method.kind == "random":
        return random_estimate(key, view, exclude)
    query_feature = query.feature / jnp.maximum(jnp.linalg.norm(query.feature), 1e-12)
    indices, similarities, valid = rank_imprints(
        view.features @ query_feature, view.openings, view.imprint_valid, query.opening, method.n,
        max_opening_difference_mm=max_opening_difference_mm, exclude=exclude)
    points, points_valid = query_points(query, view.mm_per_px, points_per_query)
    return estimate_pose(view, query, points, points_valid, indices, valid, method, similarities=similarities,
                         settings=settings, search=search, exclude=exclude)


@functools.partial(jax.jit, static_argnames=("method", "settings", "search", "points_per_query"))
def _localize(key, view, query, exclude, max_opening_difference_mm, method, settings, search, points_per_query):
    return localize_query(key, view, query, method, settings=settings, search=search,
                          points_per_query=points_per_query,
                          max_opening_difference_mm=max_opening_difference_mm, exclude=exclude)


def localize(
    key: PRNGKeyArray,
    tactile_map: TactileMap | LocalizationMap,
    query: Query,
    *,
    method: str | Method = "cti-icp-5",
    settings: IcpSettings = IcpSettings(),
    search: SearchSettings = SearchSettings(),
    points_per_query: int = POINTS_PER_QUERY,
    max_opening_difference_mm: float = MAX_OPENING_DIFFERENCE_MM,
    exclude: int | Int[Array, ""] = -1,
) -> PoseEstimate:
    """Estimate the pose of the sensor that took ``query`` in the object (map) frame.

    Paper section VI. Jitted: compiled once per map size, method and settings; the map, the
    query, ``exclude`` and the opening threshold are traced, so repeated calls never recompile
    (convert a :class:`~tactojax.mapping.TactileMap` once with
    :meth:`LocalizationMap.from_tactile_map` in a loop: the conversion itself is not free).

    Args:
        key: PRNG key (RANDOM's draw; the other methods are deterministic).
        tactile_map: the object's map (features filled by an encoder).
        query: the new imprint (predicted heightmap, mask, features, opening).
        method: ``"random"``, ``"cti"``, ``"cti-icp-N"``, ``"cti-icp-multistart-N"`` or
            ``"cti-search-N"``.
        settings: ICP parameters.
        search: hypothesis search parameters (``"cti-search-N"``).
        points_per_query: contact points sampled from the query for ICP.
        max_opening_difference_mm: CTI's opening filter, mm.
        exclude: a map imprint never used (leave-one-out), -1 for none.

    Returns:
        :class:`PoseEstimate`; never NaN (``converged`` False when it failed).

    Raises:
        ValueError: the query's mask is empty (no contact). Under ``jit``/``vmap`` this cannot be
            checked; such a query then comes back at its start pose with ``converged`` False.
    """
    if parse_method(method).kind == "belief":
        raise ValueError("localize() runs one-shot methods; the belief keeps state across touches: use "
                         "update_belief with build_map_surface (tactojax.localize)")
    if not isinstance(query.mask, jax.core.Tracer) and not np.any(np.asarray(query.mask)):
        raise ValueError("the query shows no contact (its mask is empty): there is nothing to localize")
    view = as_localization_map(tactile_map)
    # NumPy scalars, not jnp.asarray: they travel with the call instead of costing a device
    # dispatch each (about 0.3 ms per touch on CPU), and are strongly typed (no recompilation).
    exclude = exclude.astype(jnp.int32) if isinstance(exclude, jax.Array) else np.int32(exclude)
    return _localize(key, view, canonical_query(query), exclude, np.float32(max_opening_difference_mm),
                     parse_method(method), settings, search, points_per_query)
