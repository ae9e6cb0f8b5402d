"""A map as one stitched point cloud: voxel downsampling and distance to the true surface."""

from __future__ import annotations

import numpy as np

from tactojax.mapping._map import TactileMap


def voxel_downsample(
    points: np.ndarray, normals: np.ndarray, voxel_mm: float
) -> tuple[np.ndarray, np.ndarray]:
    """Average the points (and normals) that fall into each cubic voxel.

    Args:
        points: (N, 3) mm.
        normals: (N, 3) unit normals.
        voxel_mm: voxel edge, mm (<= 0 keeps every point).

    Returns:
        (M, 3) points and (M, 3) unit normals, one per occupied voxel, M <= N.
    """
    points = np.asarray(points, np.float64)
    normals = np.asarray(normals, np.float64)
    if voxel_mm <= 0 or len(points) == 0:
        return points.astype(np.float32), normals.astype(np.float32)
    _, voxel, counts = np.unique(np.floor(points / voxel_mm).astype(np.int64), axis=0,
                                 return_inverse=True, return_counts=True)
    voxel = voxel.reshape(-1)
    mean_points = np.zeros((len(counts), 3))
    mean_normals = np.zeros((len(counts), 3))
    np.add.at(mean_points, voxel, points)
    np.add.at(mean_normals, voxel, normals)
    mean_points /= counts[:, None]
    mean_normals /= np.maximum(np.linalg.norm(mean_normals, axis=1, keepdims=True), 1e-12)
    return mean_points.astype(np.float32), mean_normals.astype(np.float32)


def stitched_point_cloud(tactile_map: TactileMap, *, voxel_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Every valid contact point of the map in the object frame, optionally voxel-downsampled.

    Returns:
        (M, 3) points in mm and (M, 3) unit normals, object frame.
    """
    valid = np.asarray(tactile_map.point_valid).reshape(-1)
    points = np.asarray(tactile_map.points_object).reshape(-1, 3)[valid]
    normals = np.asarray(tactile_map.normals_object).reshape(-1, 3)[valid]
    return voxel_downsample(points, normals, voxel_mm)


def point_surface_distances(obj, points: np.ndarray) -> np.ndarray:
    """Unsigned distance of every point to the object's true surface, mm.

    Args:
        obj: the mapped :class:`~tactojax.objects.TactileObject` (analytic or mesh), whose
            frame is the map frame.
        points: (N, 3) map points, mm.

    Returns:
        (N,) distances in mm.
    """
    if obj.is_mesh:
        _, distance, _ = obj.solid.mesh.nearest.on_surface(np.asarray(points, np.float64))
        return np.asarray(distance)
    return np.abs(np.asarray(obj.solid.sdf(np.asarray(points, np.float32))))


def surface_distance(obj, points: np.ndarray) -> dict[str, float]:
    """How far map points lie from the true surface: distance statistics, mm.

    Args:
        obj: the mapped :class:`~tactojax.objects.TactileObject` (analytic or mesh), whose
            frame is the map frame.
        points: (N, 3) map points, mm.

    Returns:
        ``{"mean", "median", "p95", "max", "count"}``.
    """
    if len(points) == 0:
        raise ValueError("the map has no contact points")
    distance = point_surface_distances(obj, points)
    return {"mean": float(distance.mean()), "median": float(np.median(distance)),
            "p95": float(np.percentile(distance, 95)), "max": float(distance.max()),
            "count": int(len(points))}
