"""Triangle-mesh objects: mounting in a canonical frame and fast CPU ray casting (Embree)."""

from __future__ import annotations

import numpy as np
import trimesh

from tactojax.objects._raycast import RayHits


def mount_mesh(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Copy of ``mesh`` in its canonical object frame.

    The frame is the mesh's oriented bounding box, centred, with axes ordered so that x is the
    longest extent, z the middle one and y the shortest: at yaw 0 and object turn 0 the
    mapping protocol's gripper (closing along y) pinches the object across its thinnest
    dimension, the way one picks up scissors or a box.
    """
    mounted = mesh.copy()
    obb = mounted.bounding_box_oriented.primitive
    mounted.apply_transform(np.linalg.inv(obb.transform))
    order = np.argsort(-np.asarray(obb.extents))  # longest, middle, shortest
    longest, middle, shortest = order
    rotation = np.zeros((3, 3))
    rotation[0, longest] = 1.0  # new x <- longest
    rotation[2, middle] = 1.0  # new z <- middle
    rotation[1, shortest] = 1.0  # new y <- shortest
    if np.linalg.det(rotation) < 0:
        rotation[2] *= -1.0
    transform = np.eye(4)
    transform[:3, :3] = rotation
    mounted.apply_transform(transform)
    return mounted


class MeshSolid:
    """A watertight triangle mesh in mm, ray cast with Embree (via trimesh + embreex).

    Not a JAX type: ray casting runs on the host with numpy arrays.
    """

    def __init__(self, mesh: trimesh.Trimesh):
        self.mesh = mesh
        try:
            from trimesh.ray.ray_pyembree import RayMeshIntersector
        except ImportError:  # pragma: no cover - embreex is a dependency
            from trimesh.ray.ray_triangle import RayMeshIntersector
        self._intersector = RayMeshIntersector(mesh)
        self._triangles = np.asarray(mesh.triangles, dtype=np.float64)
        self._normals = np.asarray(mesh.face_normals, dtype=np.float64)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) axis-aligned bounds (min, max) in the object frame, mm."""
        return np.asarray(self.mesh.bounds, dtype=np.float64)

    def cast(self, origins: np.ndarray, directions: np.ndarray, *, max_distance: float) -> RayHits:
        """First hit of each ray (origins/directions (..., 3), object frame, mm)."""
        batch_shape = origins.shape[:-1]
        o = np.asarray(origins, np.float64).reshape(-1, 3)
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        triangle = np.asarray(self._intersector.intersects_first(o, d))
        found = triangle >= 0
        index = np.where(found, triangle, 0)
        normals = self._normals[index]
        # Exact distance to the hit triangle's plane.
        denominator = np.einsum("ij,ij->i", normals, d)
        safe = np.where(np.abs(denominator) > 1e-12, denominator, 1.0)
        distance = np.einsum("ij,ij->i", normals, self._triangles[index, 0] - o) / safe
        # The first surface met is a back face when the ray starts inside the solid.
        starts_inside = found & (denominator > 0)
        hit = found & ~starts_inside & (distance >= 0) & (distance < max_distance)
        distance = np.where(hit, distance, max_distance)
        return RayHits(
            distance=distance.reshape(batch_shape).astype(np.float32),
            hit=hit.reshape(batch_shape),
            starts_inside=starts_inside.reshape(batch_shape),
        )
