"""Heightmap -> points / normals / gradients, against numpy and closed forms."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tactojax.geometry import (
    contact_points, heightmap_gradient, heightmap_normals, heightmap_to_points, pixel_grid,
)

H, W, MM_PER_PX = 30, 40, 0.4

_gradient_jit = jax.jit(heightmap_gradient, static_argnums=1)
_normals_jit = jax.jit(heightmap_normals, static_argnums=1)
_points_jit = jax.jit(heightmap_to_points, static_argnums=1)
_contact_points_jit = jax.jit(contact_points, static_argnums=2)


def _numpy_grid(height: int, width: int, mm_per_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of pixel centres, mm, from the documented formula, built independently."""
    x = np.empty((height, width))
    y = np.empty((height, width))
    for r in range(height):
        for c in range(width):
            x[r, c] = (c - (width - 1) / 2) * mm_per_px
            y[r, c] = (r - (height - 1) / 2) * mm_per_px
    return x, y


@pytest.mark.parametrize("shape", [(30, 40), (7, 5), (8, 8)])
def test_pixel_grid_vs_numpy(shape):
    x, y = _numpy_grid(*shape, 0.25)
    grid = np.asarray(pixel_grid(*shape, 0.25))
    assert grid.shape == shape + (2,)
    np.testing.assert_allclose(grid[..., 0], x, atol=1e-6)
    np.testing.assert_allclose(grid[..., 1], y, atol=1e-6)
    # Centred: the grid's mean is the sensor origin.
    np.testing.assert_allclose(grid.reshape(-1, 2).mean(0), [0, 0], atol=1e-5)


def _plane(a: float, b: float, c: float) -> np.ndarray:
    x, y = _numpy_grid(H, W, MM_PER_PX)
    return a * x + b * y + c


@pytest.mark.parametrize("a,b", [(0.0, 0.0), (0.3, -0.1), (-0.5, 0.7)])
@pytest.mark.parametrize("jit", [False, True])
def test_plane_slope_and_normals(a, b, jit):
    """h = a x + b y + c: slope (a, b) everywhere, normal (-a, -b, -1) / norm everywhere."""
    h = jnp.asarray(_plane(a, b, 1.5), jnp.float32)
    grad_fn, normals_fn = (_gradient_jit, _normals_jit) if jit else (heightmap_gradient, heightmap_normals)
    slope = np.asarray(grad_fn(h, MM_PER_PX))
    assert slope.shape == (H, W, 2)
    np.testing.assert_allclose(slope[..., 0], a, atol=1e-4)
    np.testing.assert_allclose(slope[..., 1], b, atol=1e-4)
    normals = np.asarray(normals_fn(h, MM_PER_PX))
    expected = np.array([-a, -b, -1.0]) / np.sqrt(a * a + b * b + 1.0)
    np.testing.assert_allclose(normals, np.broadcast_to(expected, normals.shape), atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-6)


def test_normals_are_perpendicular_to_surface():
    """The normal is orthogonal to the surface's tangent vectors (1, 0, -h_x), (0, 1, -h_y)."""
    a, b = 0.4, -0.25
    normals = np.asarray(heightmap_normals(jnp.asarray(_plane(a, b, 0.0), jnp.float32), MM_PER_PX))
    # Surface z = -h: tangents d/dx = (1, 0, -a), d/dy = (0, 1, -b).
    np.testing.assert_allclose(normals @ np.array([1.0, 0.0, -a]), 0.0, atol=1e-5)
    np.testing.assert_allclose(normals @ np.array([0.0, 1.0, -b]), 0.0, atol=1e-5)
    # Pointing towards the sensor (-z side).
    assert np.all(normals[..., 2] < 0)


@pytest.mark.parametrize("jit", [False, True])
def test_paraboloid_gradient_matches_analytic_inside(jit):
    """h = k ((x - x0)^2 + 2 (y - y0)^2): central differences are exact for quadratics."""
    k, x0, y0 = 0.05, 1.1, -0.7
    x, y = _numpy_grid(H, W, MM_PER_PX)
    h = k * ((x - x0) ** 2 + 2.0 * (y - y0) ** 2)
    fn = _gradient_jit if jit else heightmap_gradient
    slope = np.asarray(fn(jnp.asarray(h, jnp.float32), MM_PER_PX))
    inner = (slice(1, -1), slice(1, -1))
    np.testing.assert_allclose(slope[..., 0][inner], (2 * k * (x - x0))[inner], atol=2e-4)
    np.testing.assert_allclose(slope[..., 1][inner], (4 * k * (y - y0))[inner], atol=2e-4)
    # Whole image, borders included, agrees with numpy's gradient (one-sided at the borders).
    dh_drow, dh_dcol = np.gradient(h, MM_PER_PX)
    np.testing.assert_allclose(slope[..., 0], dh_dcol, atol=2e-4)
    np.testing.assert_allclose(slope[..., 1], dh_drow, atol=2e-4)


def test_sphere_cap_normals_match_sphere_normals():
    """A spherical cap pressed into the gel: normals are the sphere's outward normals."""
    R, depth = 6.0, 1.0
    x, y = _numpy_grid(H, W, MM_PER_PX)
    r2 = x**2 + y**2
    # Sphere centre at z = R - depth (sensor frame); its surface facing the gel is
    # z = zc - sqrt(R^2 - r^2) = -h.
    zc = R - depth
    inside = r2 < (R**2 - zc**2) * 0.8  # well inside the patch
    h = np.where(r2 < R**2, np.sqrt(np.maximum(R**2 - r2, 0)) - zc, 0.0)
    h = np.maximum(h, 0.0)
    normals = np.asarray(heightmap_normals(jnp.asarray(h, jnp.float32), MM_PER_PX))
    z = -h
    outward = np.stack([x, y, z - zc], -1) / R
    # Central differences on a sphere: error O(px^2 * curvature^2) away from the patch edge.
    interior = inside & np.pad(np.ones((H - 2, W - 2), bool), 1)
    np.testing.assert_allclose(normals[interior], outward[interior], atol=5e-3)


@pytest.mark.parametrize("jit", [False, True])
def test_heightmap_to_points_vs_numpy(jit):
    rng = np.random.default_rng(0)
    h = rng.uniform(0.0, 2.0, size=(H, W))
    fn = _points_jit if jit else heightmap_to_points
    points = np.asarray(fn(jnp.asarray(h, jnp.float32), MM_PER_PX))
    x, y = _numpy_grid(H, W, MM_PER_PX)
    np.testing.assert_allclose(points, np.stack([x, y, -h], -1), atol=1e-5)


@pytest.mark.parametrize("jit", [False, True])
def test_contact_points_flattening_and_mask(jit):
    rng = np.random.default_rng(1)
    a, b = 0.2, -0.3
    h = _plane(a, b, 3.0) + 0.0
    mask = rng.uniform(size=(H, W)) < 0.3
    fn = _contact_points_jit if jit else contact_points
    points, normals, valid = fn(jnp.asarray(h, jnp.float32), jnp.asarray(mask), MM_PER_PX)
    points, normals, valid = map(np.asarray, (points, normals, valid))
    assert points.shape == (H * W, 3) and normals.shape == (H * W, 3) and valid.shape == (H * W,)
    np.testing.assert_array_equal(valid, mask.reshape(-1))
    x, y = _numpy_grid(H, W, MM_PER_PX)
    # Row-major flattening: index r * W + c is pixel (r, c).
    for r, c in [(0, 0), (0, W - 1), (H - 1, 0), (12, 17)]:
        np.testing.assert_allclose(points[r * W + c], [x[r, c], y[r, c], -h[r, c]], atol=1e-5)
    expected_normal = np.array([-a, -b, -1.0]) / np.sqrt(a * a + b * b + 1)
    np.testing.assert_allclose(normals, np.broadcast_to(expected_normal, normals.shape), atol=1e-5)
    # The valid points are exactly the masked pixels' (x, y, -h).
    np.testing.assert_allclose(points[valid], np.stack([x, y, -h], -1)[mask], atol=1e-5)


def test_vmap_matches_python_loop():
    rng = np.random.default_rng(2)
    hs = jnp.asarray(rng.uniform(0.0, 1.0, size=(3, H, W)), jnp.float32)
    batched = jax.vmap(lambda h: heightmap_normals(h, MM_PER_PX))(hs)
    looped = jnp.stack([heightmap_normals(h, MM_PER_PX) for h in hs])
    np.testing.assert_allclose(np.asarray(batched), np.asarray(looped), atol=1e-6)
    batched_p = jax.vmap(lambda h: heightmap_to_points(h, MM_PER_PX))(hs)
    looped_p = jnp.stack([heightmap_to_points(h, MM_PER_PX) for h in hs])
    np.testing.assert_allclose(np.asarray(batched_p), np.asarray(looped_p), atol=1e-6)


def test_normals_gradient_check():
    """heightmap_normals is differentiable: check_grads on a smooth random bump."""
    from jax.test_util import check_grads

    x, y = _numpy_grid(8, 8, MM_PER_PX)
    h = jnp.asarray(0.3 * np.exp(-(x**2 + y**2) / 2.0), jnp.float32)
    w = jnp.asarray(np.random.default_rng(3).normal(size=(8, 8, 3)), jnp.float32)
    loss = jax.jit(lambda h_: jnp.sum(heightmap_normals(h_, MM_PER_PX) * w))
    check_grads(loss, (h,), order=1, modes=["rev"], eps=1e-2, atol=2e-2, rtol=2e-2)
