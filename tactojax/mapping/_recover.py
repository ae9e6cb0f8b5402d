"""Shape recovery from a whole tactile map (paper section V, Table II)."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import PRNGKeyArray

from tactojax.mapping._build import sample_contact_pixels
from tactojax.mapping._cloud import stitched_point_cloud, voxel_downsample
from tactojax.mapping._map import TactileMap
from tactojax.mapping._packing import unpack_heightmaps
from tactojax.mapping._reliable import depth_observed, membrane_skirt
from tactojax.mapping._shape_fit import ShapeFit, fit_shape

POINT_BUCKET = 4096
"""Clouds are padded to a multiple of this many points, so that maps of similar size share one
compiled fit."""

_BATCH = 64  # imprints per compiled refinement batch (the last one is padded)


@functools.partial(jax.jit, static_argnames=("mm_per_px", "count"))
def _refined_pixels(keys, packed_heightmaps, *, mm_per_px: float, count: int):
    """Contact (not skirt) and depth-observed contact pixels of a batch of imprints."""
    def one(key, packed):
        heightmap, mask = unpack_heightmaps(packed)
        contact = mask & ~membrane_skirt(heightmap, mm_per_px)
        observed = contact & depth_observed(heightmap, mm_per_px)
        contact_key, observed_key = jax.random.split(key)
        contact_pixels, contact_valid = sample_contact_pixels(contact_key, contact, count)
        observed_pixels, observed_valid = sample_contact_pixels(observed_key, observed, count)
        return observed_pixels, observed_valid, contact_pixels, contact_valid

    return jax.vmap(one)(keys, packed_heightmaps)


def shape_fit_clouds(
    tactile_map: TactileMap,
    *,
    refine_contact: bool = True,
    key: PRNGKeyArray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The two clouds a shape fit uses, in the map (object) frame.

    With ``refine_contact`` the points are drawn afresh from the map's predicted heightmaps, as
    many per imprint as the map holds, from its contact masks less the membrane skirt
    (:func:`~tactojax.mapping.membrane_skirt`): the *contact* cloud, which says where the surface
    stops; and from those pixels the ones whose depth the sensor observed
    (:func:`~tactojax.mapping.depth_observed`): the *depth* cloud, which says where the surface
    lies. Without it both are the map's own points. The map itself is not changed.

    Args:
        tactile_map: the object's map.
        refine_contact: drop skirt and unobserved-depth pixels (see above).
        key: PRNG key for the point sampling (default ``jax.random.key(0)``).

    Returns:
        (depth points (N, 3), contact points (M, 3)), mm, object frame.
    """
    if not refine_contact:
        points, _ = stitched_point_cloud(tactile_map)
        return points, points
    key = jax.random.key(0) if key is None else key
    count, per_imprint = tactile_map.point_pixels.shape[:2]
    parts = []
    for start in range(0, count, _BATCH):
        index = np.minimum(np.arange(start, start + _BATCH), count - 1)
        keys = jax.random.split(jax.random.fold_in(key, start), _BATCH)
        outputs = _refined_pixels(keys, tactile_map.packed_heightmaps[index], mm_per_px=float(tactile_map.mm_per_px),
                                  count=per_imprint)
        parts.append([np.asarray(x)[: min(_BATCH, count - start)] for x in outputs])
    observed, observed_valid, contact, contact_valid = (np.concatenate(column) for column in zip(*parts))
    imprint_valid = np.asarray(tactile_map.imprint_valid)[:, None]

    def place(pixels, valid):
        placed = tactile_map.replace(point_pixels=jnp.asarray(pixels, tactile_map.point_pixels.dtype),
                                     valid=jnp.asarray(valid & imprint_valid))
        return stitched_point_cloud(placed)[0]

    return place(observed, observed_valid), place(contact, contact_valid)


def _padded(points: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    padded = np.zeros((size, 3), np.float32)
    padded[: len(points)] = points
    return padded, np.arange(size) < len(points)


def _bucket(count: int) -> int:
    return POINT_BUCKET * max(1, math.ceil(count / POINT_BUCKET))


def fit_tactile_map(
    tactile_map: TactileMap,
    kind: str,
    *,
    voxel_mm: float = 0.5,
    robust_scale_mm: float = 0.5,
    refine_contact: bool = True,
    pad_to: int | None = None,
) -> ShapeFit:
    """Fit a Table II shape to a map's contact points.

    The surface is fitted to the depth cloud of :func:`shape_fit_clouds` (voxel-downsampled);
    where the surface stops (untouched ends and faces) comes from its contact cloud at full
    resolution (voxel centroids would sit up to half a voxel inside an edge).

    Args:
        tactile_map: the object's map.
        kind: one of ``SHAPE_KINDS``.
        voxel_mm: the depth cloud is voxel-downsampled first (mm; 0 keeps every point), so that
            densely touched regions do not outweigh the rest.
        robust_scale_mm: scale of the robust loss, mm (see :func:`fit_shape`).
        refine_contact: fit contact pixels only, and depth only where observed (see
            :func:`shape_fit_clouds`); False fits the map's own points.
        pad_to: pad the depth cloud to exactly this many points (the fit compiles once per
            size); default: the next multiple of ``POINT_BUCKET``. Clouds larger than ``pad_to``
            are an error.

    Returns:
        The :class:`ShapeFit`, in the map (object) frame.
    """
    depth_points, contact_points = shape_fit_clouds(tactile_map, refine_contact=refine_contact)
    if len(depth_points) == 0 and len(contact_points) == 0:
        raise ValueError(f"the map of {tactile_map.object_id} has no contact points to fit")
    return fit_shape_to_clouds(depth_points, contact_points, kind, voxel_mm=voxel_mm,
                               robust_scale_mm=robust_scale_mm, pad_to=pad_to)


def fit_shape_to_clouds(
    depth_points: np.ndarray,
    contact_points: np.ndarray,
    kind: str,
    *,
    voxel_mm: float = 0.5,
    robust_scale_mm: float = 0.5,
    pad_to: int | None = None,
) -> ShapeFit:
    """:func:`fit_tactile_map` from the two clouds of :func:`shape_fit_clouds`, already drawn.

    Args:
        depth_points: (N, 3) points whose depth is trusted, mm, map frame (the surface is fitted
            to them, voxel-downsampled); when empty, the contact points are fitted instead.
        contact_points: (M, 3) contact points, mm, map frame (where the surface stops).
        kind, voxel_mm, robust_scale_mm, pad_to: as :func:`fit_tactile_map`.

    Returns:
        The :class:`ShapeFit`, in the map (object) frame.
    """
    if len(depth_points) == 0:  # no depth observed anywhere: fit the contact points after all
        depth_points = contact_points
    if len(depth_points) == 0:
        raise ValueError("no contact points to fit")
    points, _ = voxel_downsample(depth_points, np.zeros_like(depth_points), voxel_mm)
    size = _bucket(len(points)) if pad_to is None else pad_to
    if size < len(points):
        raise ValueError(f"the cloud has {len(points)} points, more than pad_to={pad_to}")
    padded, valid = _padded(points, size)
    extent_points, extent_valid = _padded(contact_points, _bucket(len(contact_points)))
    return fit_shape(padded, valid, kind, robust_scale_mm=robust_scale_mm, extent_points=extent_points,
                     extent_valid=extent_valid)
