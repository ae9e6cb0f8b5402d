"""Shape recovery from a whole tactile map (paper section V, Table II)."""

from __future__ import annotations

import math

import numpy as np

from tactojax.mapping._cloud import stitched_point_cloud
from tactojax.mapping._map import TactileMap
from tactojax.mapping._shape_fit import ShapeFit, fit_shape

POINT_BUCKET = 4096
"""Clouds are padded to a multiple of this many points, so that maps of similar size share one
compiled fit."""


def fit_tactile_map(
    tactile_map: TactileMap,
    kind: str,
    *,
    voxel_mm: float = 0.5,
    robust_scale_mm: float = 0.5,
    pad_to: int | None = None,
) -> ShapeFit:
    """Fit a Table II shape to a map's stitched contact cloud.

    Args:
        tactile_map: the object's map.
        kind: one of ``SHAPE_KINDS``.
        voxel_mm: the cloud is voxel-downsampled first (mm; 0 keeps every point), so that densely
            touched regions do not outweigh the rest.
        robust_scale_mm: scale of the robust loss, mm (see :func:`fit_shape`).
        pad_to: pad the cloud to exactly this many points (the fit compiles once per size);
            default: the next multiple of ``POINT_BUCKET``. Clouds larger than ``pad_to`` are
            an error.

    Returns:
        The :class:`ShapeFit`, in the map (object) frame.
    """
    points, _ = stitched_point_cloud(tactile_map, voxel_mm=voxel_mm)
    if len(points) == 0:
        raise ValueError(f"the map of {tactile_map.object_id} has no contact points to fit")
    size = POINT_BUCKET * math.ceil(len(points) / POINT_BUCKET) if pad_to is None else pad_to
    if size < len(points):
        raise ValueError(f"the cloud has {len(points)} points, more than pad_to={pad_to}")
    padded = np.zeros((size, 3), np.float32)
    padded[: len(points)] = points
    valid = np.arange(size) < len(points)
    return fit_shape(padded, valid, kind, robust_scale_mm=robust_scale_mm)
