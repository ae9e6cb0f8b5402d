"""Analytic ray casting against trimesh's ray caster and a dense-sampling numpy reference.

* Primitives (and a ``Placed`` one) are compared with trimesh's exact float64 triangle ray
  caster on finely tessellated meshes: distances agree within the tessellation error, hits
  and misses agree wherever the ray is not grazing the surface.
* ``Union`` / ``Difference`` (trimesh has no boolean-free equivalent) are compared with a
  numpy reference: dense sampling of closed-form membership along the ray, refined by
  bisection.
* Every hit point lies on the surface (``sdf ~ 0``) for every primitive and every analytic
  catalog object; hit distances are differentiable (closed-form radius derivative, and
  ``check_grads`` with respect to the ray origins).
"""

from __future__ import annotations

import zlib

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
import trimesh
from jax.test_util import check_grads
from scipy.spatial.transform import Rotation
from trimesh.ray.ray_triangle import RayMeshIntersector

from tactojax.io import MissingDataPackageError
from tactojax.objects import (
    CATALOG, Box, Cylinder, Difference, Frustum, Placed, Sphere, SquareFrustum, Union, get_object,
    raycast,
)

MAX_DISTANCE = 200.0
N_RAYS = 256  # one ray-batch shape everywhere, so each solid's raycast compiles once
_raycast_jit = jax.jit(raycast, static_argnames=("max_distance",))


def _f(x) -> jax.Array:
    return jnp.asarray(x, jnp.float32)


# ---------------------------------------------------------------- closed-form membership (numpy)

def _in_sphere(p, R):
    return np.sum(p * p, -1) <= R * R


def _in_box(p, half):
    return np.all(np.abs(p) <= half, -1)


def _in_cylinder(p, r, h):
    return (p[..., 0] ** 2 + p[..., 1] ** 2 <= r * r) & (np.abs(p[..., 2]) <= h)


def _in_frustum(p, r1, r2, h):
    radius = r1 + (r2 - r1) * (p[..., 2] + h) / (2 * h)
    return (p[..., 0] ** 2 + p[..., 1] ** 2 <= radius**2) & (np.abs(p[..., 2]) <= h)


def _in_square_frustum(p, s1, s2, h):
    half_side = 0.5 * (s1 + (s2 - s1) * (p[..., 2] + h) / (2 * h))
    return (np.abs(p[..., 0]) <= half_side) & (np.abs(p[..., 1]) <= half_side) & (np.abs(p[..., 2]) <= h)


def _transform_points(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """p_solid from p_parent for the 4x4 pose T_parent_solid."""
    return (p - T[:3, 3]) @ T[:3, :3]


# ---------------------------------------------------------------- meshes (trimesh.creation)

def _frustum_mesh(r1, r2, h, sections=512):
    mesh = trimesh.creation.cylinder(radius=1.0, height=2 * h, sections=sections)
    v = mesh.vertices.copy()
    radius = r1 + (r2 - r1) * (v[:, 2] + h) / (2 * h)
    v[:, :2] *= radius[:, None]
    return trimesh.Trimesh(v, mesh.faces, process=False)


def _square_frustum_mesh(s1, s2, h):
    mesh = trimesh.creation.box(extents=[1.0, 1.0, 2 * h])
    v = mesh.vertices.copy()
    side = s1 + (s2 - s1) * (v[:, 2] + h) / (2 * h)
    v[:, :2] *= side[:, None]
    return trimesh.Trimesh(v, mesh.faces, process=False)


_ROTATION = Rotation.from_rotvec([0.4, -0.9, 0.3]).as_matrix()
_T_PLACED = np.eye(4)
_T_PLACED[:3, :3] = _ROTATION
_T_PLACED[:3, 3] = [2.0, -1.5, 3.0]


def _placed(solid):
    return Placed(solid, jaxlie.SE3.from_matrix(jnp.asarray(_T_PLACED, jnp.float32)))


def _placed_mesh(mesh):
    mesh = mesh.copy()
    mesh.apply_transform(_T_PLACED)
    return mesh


# name -> (solid, mesh, membership(p), tessellation tolerance mm, bounding radius mm)
PRIMITIVES = {
    "sphere": (Sphere(_f(6.0)), trimesh.creation.icosphere(subdivisions=5, radius=6.0),
               lambda p: _in_sphere(p, 6.0), 3e-3, 6.0),
    "box": (Box(_f([4.0, 2.5, 3.0])), trimesh.creation.box(extents=[8.0, 5.0, 6.0]),
            lambda p: _in_box(p, [4.0, 2.5, 3.0]), 1e-4, 5.6),
    "cylinder": (Cylinder(_f(5.0), _f(3.0)), trimesh.creation.cylinder(radius=5.0, height=6.0, sections=512),
                 lambda p: _in_cylinder(p, 5.0, 3.0), 2e-4, 5.9),
    "frustum": (Frustum(_f(8.0), _f(2.0), _f(3.0)), _frustum_mesh(8.0, 2.0, 3.0),
                lambda p: _in_frustum(p, 8.0, 2.0, 3.0), 4e-4, 8.6),
    "frustum_widening": (Frustum(_f(3.0), _f(6.0), _f(4.0)), _frustum_mesh(3.0, 6.0, 4.0),
                         lambda p: _in_frustum(p, 3.0, 6.0, 4.0), 4e-4, 7.3),
    "square_frustum": (SquareFrustum(_f(14.0), _f(4.0), _f(2.5)), _square_frustum_mesh(14.0, 4.0, 2.5),
                       lambda p: _in_square_frustum(p, 14.0, 4.0, 2.5), 1e-4, 10.2),
    "placed_frustum": (_placed(Frustum(_f(8.0), _f(2.0), _f(3.0))), _placed_mesh(_frustum_mesh(8.0, 2.0, 3.0)),
                       lambda p: _in_frustum(_transform_points(_T_PLACED, p), 8.0, 2.0, 3.0), 4e-4, 13.0),
}


def _outside_rays(rng, n, radius, target_radius, centre=(0.0, 0.0, 0.0)):
    """Rays from a sphere of ``radius`` around ``centre`` aimed at points within ``target_radius``."""
    centre = np.asarray(centre, np.float64)
    start = rng.normal(size=(n, 3))
    origins = centre + radius * start / np.linalg.norm(start, axis=-1, keepdims=True)
    targets = centre + rng.uniform(-target_radius, target_radius, size=(n, 3))
    directions = targets - origins
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    return origins, directions


def _mesh_first_hits(mesh, origins, directions):
    """(distance, hit, triangle normal . direction) of each ray's first hit, exact float64."""
    locations, ray_index, tri_index = RayMeshIntersector(mesh).intersects_location(
        origins, directions, multiple_hits=True)
    distance = np.full(len(origins), np.inf)
    cosine = np.zeros(len(origins))
    t = np.einsum("ij,ij->i", locations - origins[ray_index], directions[ray_index])
    for i, ti, tri in zip(ray_index, t, tri_index):
        if 0 < ti < distance[i]:
            distance[i] = ti
            cosine[i] = mesh.face_normals[tri] @ directions[i]
    return distance, np.isfinite(distance), cosine


@jax.jit
def _sdf(solid, points):
    return solid.sdf(points)


def _closest_margin(solid, origins, directions, t_max, n=2000):
    """Smallest sdf along each ray (dense samples): how close the ray comes to grazing."""
    t = np.linspace(0.0, t_max, n)
    points = origins[:, None, :] + t[None, :, None] * directions[:, None, :]
    return np.min(np.asarray(_sdf(solid, jnp.asarray(points, jnp.float32))), axis=1)


@pytest.mark.parametrize("name", sorted(PRIMITIVES))
def test_primitive_vs_trimesh(name):
    solid, mesh, _, tol, _ = PRIMITIVES[name]
    assert mesh.is_watertight
    bound = np.linalg.norm(mesh.extents) / 2
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    origins, directions = _outside_rays(rng, N_RAYS, 3.0 * bound, 0.8 * bound, centre=mesh.bounds.mean(0))
    hits = _raycast_jit(solid, _f(origins), _f(directions), max_distance=MAX_DISTANCE)
    distance, hit = np.asarray(hits.distance, np.float64), np.asarray(hits.hit)
    assert not np.any(np.asarray(hits.starts_inside))
    ref_distance, ref_hit, cosine = _mesh_first_hits(mesh, origins, directions)
    assert 0.2 * len(origins) < ref_hit.sum() < 0.95 * len(origins)  # both hits and misses
    # Hit/miss: must agree wherever the ray passes farther than the tessellation error from the
    # surface (min sdf along the ray either clearly < 0 or clearly > 0).
    margin = _closest_margin(solid, origins, directions, 6.0 * bound)
    robust = np.abs(margin) > 10 * tol + 1e-3
    np.testing.assert_array_equal(hit[robust], ref_hit[robust])
    assert robust.mean() > 0.9
    # Where both hit, distances agree within the tessellation error over the incidence cosine.
    both = hit & ref_hit
    transversal = both & (np.abs(cosine) > 0.2)
    assert transversal.sum() > 40
    error = np.abs(distance - ref_distance)
    allowed = (tol + 2e-4 * 3.0 * bound) / np.maximum(np.abs(cosine), 1e-3) + 1e-4
    assert np.all(error[transversal] <= allowed[transversal]), (
        f"max error {error[transversal].max():.2e} mm")
    # Misses report max_distance.
    np.testing.assert_array_equal(distance[~hit], MAX_DISTANCE)


@pytest.mark.parametrize("name", sorted(PRIMITIVES))
def test_primitive_starts_inside(name):
    """Origins sampled around the solid: starts_inside == closed-form membership."""
    solid, mesh, inside_fn, _, bound = PRIMITIVES[name]
    rng = np.random.default_rng(7)
    centre = mesh.bounds.mean(0)
    origins = centre + rng.uniform(-1.0, 1.0, size=(N_RAYS, 3)) * (mesh.extents / 2 * 1.2)
    directions = rng.normal(size=(N_RAYS, 3))
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    # Leave out points within 1e-3 mm of the surface (float32 rounding decides those).
    clear = np.abs(np.asarray(_sdf(solid, _f(origins)))) > 1e-3
    hits = _raycast_jit(solid, _f(origins), _f(directions), max_distance=MAX_DISTANCE)
    inside = inside_fn(origins)
    assert 0.05 < inside.mean() < 0.9
    np.testing.assert_array_equal(np.asarray(hits.starts_inside)[clear], inside[clear])
    # A ray starting inside reports no hit; one starting outside in a convex solid either hits
    # or misses, never both.
    assert not np.any(np.asarray(hits.hit) & np.asarray(hits.starts_inside))
    # Also against trimesh's containment test, an independent implementation.
    np.testing.assert_array_equal(mesh.contains(origins[clear]), inside[clear])


# ---------------------------------------------------------------- Union / Difference (numpy reference)

_T_A = np.eye(4)
_T_A[:3, 3] = [2.5, 0.0, 0.5]
_T_B = np.eye(4)
_T_B[:3, :3] = Rotation.from_rotvec([0.0, 0.0, 0.6]).as_matrix()
_T_B[:3, 3] = [-2.0, 1.0, 0.0]


def _translation(x, y, z) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = [x, y, z]
    return T


def _placed_at(solid, T):
    return Placed(solid, jaxlie.SE3.from_matrix(jnp.asarray(T, jnp.float32)))


COMPOSITES = {
    # Overlapping sphere + rotated box.
    "union_sphere_box": (
        Union((_placed_at(Sphere(_f(3.0)), _T_A), _placed_at(Box(_f([3.0, 2.0, 2.5])), _T_B))),
        lambda p: _in_sphere(_transform_points(_T_A, p), 3.0)
        | _in_box(_transform_points(_T_B, p), [3.0, 2.0, 2.5]),
        7.0,
    ),
    # Disjoint-ish: two coaxial cylinders (like the catalog's double cylinder).
    "union_cylinders": (
        Union((Cylinder(_f(4.0), _f(2.0)), _placed_at(Cylinder(_f(2.0), _f(3.0)), _translation(0, 0, 5.0)))),
        lambda p: _in_cylinder(p, 4.0, 2.0) | _in_cylinder(p - [0, 0, 5.0], 2.0, 3.0),
        8.0,
    ),
    # Tube (a ring-shaped imprint): a cylinder with a through bore.
    "difference_tube": (
        Difference(Cylinder(_f(5.0), _f(3.0)), Cylinder(_f(2.5), _f(6.0))),
        lambda p: _in_cylinder(p, 5.0, 3.0) & ~_in_cylinder(p, 2.5, 6.0),
        6.0,
    ),
    # Box with a spherical dent in its top face.
    "difference_dent": (
        Difference(Box(_f([5.0, 5.0, 2.0])), _placed_at(Sphere(_f(3.0)), _translation(0, 0, 3.5))),
        lambda p: _in_box(p, [5.0, 5.0, 2.0]) & ~_in_sphere(p - [0, 0, 3.5], 3.0),
        7.5,
    ),
    # Hollow semicone (catalog calibration shape).
    "difference_hollow_frustum": (
        Difference(Frustum(_f(9.0), _f(5.0), _f(2.0)), Cylinder(_f(2.5), _f(4.0))),
        lambda p: _in_frustum(p, 9.0, 5.0, 2.0) & ~_in_cylinder(p, 2.5, 4.0),
        9.5,
    ),
}


def _sampled_first_hit(inside_fn, origins, directions, t_max, step=5e-3):
    """First t >= 0 where each ray is inside: dense samples, then bisection (float64)."""
    t = np.arange(0.0, t_max, step)
    points = origins[:, None, :] + t[None, :, None] * directions[:, None, :]
    inside = inside_fn(points)
    starts_inside = inside[:, 0]
    any_inside = inside.any(axis=1)
    k = np.argmax(inside, axis=1)
    lo = t[np.maximum(k - 1, 0)]
    hi = t[k]
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        m = inside_fn(origins + mid[:, None] * directions)
        hi = np.where(m, mid, hi)
        lo = np.where(m, lo, mid)
    hit = any_inside & ~starts_inside
    return np.where(hit, hi, np.inf), hit, starts_inside


@pytest.mark.parametrize("name", sorted(COMPOSITES))
def test_composite_vs_sampled_reference(name):
    solid, inside_fn, bound = COMPOSITES[name]
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    # Rays from outside, aimed at the solid, plus rays from random points in and around it
    # (origins in the bore or inside the material).
    half = N_RAYS // 2
    o1, d1 = _outside_rays(rng, half, 2.0 * bound, 0.8 * bound)
    o2 = rng.uniform(-0.8 * bound, 0.8 * bound, size=(half, 3))
    d2 = rng.normal(size=(half, 3))
    d2 /= np.linalg.norm(d2, axis=-1, keepdims=True)
    origins, directions = np.concatenate([o1, o2]), np.concatenate([d1, d2])
    # Leave out origins within 1e-3 mm of the surface (float32 rounding decides those).
    clear = np.abs(np.asarray(_sdf(solid, _f(origins)))) > 1e-3

    hits = _raycast_jit(solid, _f(origins), _f(directions), max_distance=MAX_DISTANCE)
    ref_t, ref_hit, ref_inside = _sampled_first_hit(inside_fn, origins, directions, 3.5 * bound)
    assert ref_hit[clear].sum() > 40 and ref_inside[clear].sum() > 10
    np.testing.assert_array_equal(np.asarray(hits.starts_inside)[clear], ref_inside[clear])
    np.testing.assert_array_equal(np.asarray(hits.hit)[clear], ref_hit[clear])
    both = clear & ref_hit
    np.testing.assert_allclose(np.asarray(hits.distance)[both], ref_t[both], atol=2e-4, rtol=2e-6)


# ---------------------------------------------------------------- sdf(hit) ~ 0

@pytest.mark.parametrize("name", sorted(PRIMITIVES) + sorted(COMPOSITES))
def test_hit_points_on_surface_of_primitives(name):
    solid = PRIMITIVES[name][0] if name in PRIMITIVES else COMPOSITES[name][0]
    bound = PRIMITIVES[name][4] if name in PRIMITIVES else COMPOSITES[name][2]
    centre = np.asarray(PRIMITIVES[name][1].bounds.mean(0)) if name in PRIMITIVES else np.zeros(3)
    origins, directions = _outside_rays(np.random.default_rng(3), N_RAYS, 3.0 * bound, 0.6 * bound, centre)
    hits = _raycast_jit(solid, _f(origins), _f(directions), max_distance=MAX_DISTANCE)
    hit = np.asarray(hits.hit)
    assert hit.sum() > 60
    points = origins + np.asarray(hits.distance, np.float64)[:, None] * directions
    sdf = np.asarray(_sdf(solid, _f(points)))[hit]
    assert np.max(np.abs(sdf)) < 1e-3 * max(1.0, bound / 5), np.max(np.abs(sdf))


@pytest.mark.parametrize("name", list(CATALOG))
def test_hit_points_on_surface_of_catalog_objects(name):
    try:
        obj = get_object(name)
    except MissingDataPackageError:
        pytest.skip(f"{name}: optional data package not installed")
    if obj.is_mesh:
        pytest.skip("mesh object: ray cast by Embree, not by the analytic path")
    centre = obj.bounds.mean(0)
    half = np.linalg.norm(obj.extents) / 2
    origins, directions = _outside_rays(np.random.default_rng(5), N_RAYS, 2.0 * half, 0.5 * half, centre=centre)
    hits = _raycast_jit(obj.solid, _f(origins), _f(directions), max_distance=MAX_DISTANCE)
    hit = np.asarray(hits.hit)
    assert hit.sum() > 60
    assert not np.any(np.asarray(hits.starts_inside))
    points = origins + np.asarray(hits.distance, np.float64)[:, None] * directions
    sdf = np.asarray(_sdf(obj.solid, _f(points)))[hit]
    # float32 at up to ~100 mm from the origin: a few 1e-6 relative.
    assert np.max(np.abs(sdf)) < 2e-3 * max(1.0, half / 20), np.max(np.abs(sdf))
    # Hit points lie inside the object's bounds.
    assert np.all(points[hit] >= obj.bounds[0] - 1e-2) and np.all(points[hit] <= obj.bounds[1] + 1e-2)


# ---------------------------------------------------------------- max_distance

def test_max_distance_cuts_far_hits():
    solid = Sphere(_f(5.0))
    origins = _f([[0.0, 0.0, -20.0], [0.0, 0.0, -10.0], [0.0, 9.0, -10.0]])
    directions = _f([[0.0, 0.0, 1.0]] * 3)
    hits = raycast(solid, origins, directions, max_distance=12.0)
    # Sphere surface at z = -5: distances 15 (beyond 12), 5 (a hit) and a miss.
    np.testing.assert_array_equal(np.asarray(hits.hit), [False, True, False])
    np.testing.assert_allclose(np.asarray(hits.distance), [12.0, 5.0, 12.0], atol=1e-5)


# ---------------------------------------------------------------- gradients

def _sphere_hit_distance_closed_form(o, d, R):
    b = np.sum(o * d, -1)
    disc = b * b - np.sum(o * o, -1) + R * R
    return -b - np.sqrt(disc), -R / np.sqrt(disc)  # t, dt/dR


def test_grad_distance_wrt_sphere_radius():
    rng = np.random.default_rng(11)
    R = 6.0
    origins, directions = _outside_rays(rng, 64, 20.0, 3.0)  # all hit transversally
    t_ref, dt_dR_ref = _sphere_hit_distance_closed_form(origins, directions, R)

    def distances(radius):
        return raycast(Sphere(radius), _f(origins), _f(directions), max_distance=MAX_DISTANCE).distance

    t, dt_dR = jax.jit(jax.jvp, static_argnums=0)(distances, (_f(R),), (_f(1.0),))
    np.testing.assert_allclose(np.asarray(t), t_ref, atol=2e-5)
    np.testing.assert_allclose(np.asarray(dt_dR), dt_dR_ref, rtol=1e-4, atol=1e-5)
    # Reverse mode (jax.grad) on a scalar loss: the weighted sum of the per-ray derivatives.
    weights = np.linspace(0.5, 1.5, len(origins))
    grad = float(jax.jit(jax.grad(lambda r: jnp.sum(distances(r) * _f(weights))))(_f(R)))
    np.testing.assert_allclose(grad, np.sum(weights * dt_dR_ref), rtol=1e-4)


def test_check_grads_distance_wrt_origins():
    with jax.enable_x64(True):
        rng = np.random.default_rng(12)
        origins, directions = _outside_rays(rng, 8, 15.0, 2.5)
        directions = jnp.asarray(directions, jnp.float64)
        sphere = Sphere(jnp.asarray(6.0, jnp.float64))
        b = np.sum(origins * np.asarray(directions), -1)
        assert np.all(b * b - np.sum(origins**2, -1) + 36.0 > 4.0)  # transversal hits

        @jax.jit
        def f(o):
            return raycast(sphere, o, directions, max_distance=MAX_DISTANCE).distance

        check_grads(f, (jnp.asarray(origins, jnp.float64),), order=1, modes=["fwd", "rev"],
                    eps=1e-4, atol=1e-6, rtol=1e-6)
        # And against the closed form: dt/do = -d - (b d - o) / sqrt(disc) ... checked via jacobian.
        jac = np.asarray(jax.jacrev(lambda o: f(o).sum())(jnp.asarray(origins)))
        d = np.asarray(directions)
        disc = b * b - np.sum(origins**2, -1) + 36.0
        expected = -d - (b[:, None] * d - origins) / np.sqrt(disc)[:, None]
        np.testing.assert_allclose(jac, expected, atol=1e-9)


def test_vmap_matches_python_loop():
    solid = PRIMITIVES["frustum"][0]
    origins, directions = _outside_rays(np.random.default_rng(13), 12, 20.0, 8.0)
    origins, directions = _f(origins.reshape(3, 4, 3)), _f(directions.reshape(3, 4, 3))
    batched = jax.jit(jax.vmap(lambda o, d: raycast(solid, o, d, max_distance=MAX_DISTANCE).distance))(
        origins, directions)
    looped = jnp.stack([_raycast_jit(solid, origins[i], directions[i], max_distance=MAX_DISTANCE).distance
                        for i in range(3)])
    direct = _raycast_jit(solid, origins, directions, max_distance=MAX_DISTANCE).distance
    np.testing.assert_allclose(np.asarray(batched), np.asarray(looped), atol=1e-6)
    np.testing.assert_allclose(np.asarray(direct), np.asarray(looped), atol=1e-6)
