"""Contact model: press() and the full touch() path against closed-form sphere caps and flat faces."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
from scipy import ndimage

from tactojax.objects import get_object
from tactojax.sensor import gel_surface, gelslim, press
from tactojax.sensor._contact import MIN_INDENTATION_MM
from tactojax.simulate._touch import touch

SPEC = gelslim(scale=0.5)  # 120 x 160 px at 0.2 mm/px
H, W, PX = SPEC.height_px, SPEC.width_px, SPEC.mm_per_px
SIGMA_PX = SPEC.gel_smoothing_mm / PX

_press_jit = jax.jit(press)


def _grid() -> tuple[np.ndarray, np.ndarray]:
    """Sensor-frame pixel centres (x along columns, y along rows), mm, float64."""
    x = (np.arange(W) - (W - 1) / 2) * PX
    y = (np.arange(H) - (H - 1) / 2) * PX
    return np.meshgrid(x, y, indexing="xy")


def _sphere_distances(R, x0, y0, z0):
    """Distance along +z from the gel plane z = 0 to a sphere (closed form), and the hit mask."""
    x, y = _grid()
    r2 = (x - x0) ** 2 + (y - y0) ** 2
    hit = r2 < R * R
    return np.where(hit, z0 - np.sqrt(np.maximum(R * R - r2, 0.0)), 0.0), hit, r2


def _cap(R, depth, r2):
    """Closed-form spherical cap indentation of a sphere pressed `depth` past first contact."""
    return np.maximum(0.0, depth - (R - np.sqrt(np.maximum(R * R - r2, 0.0))))


def _rmse(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - b) ** 2)))


def _reference_gel(rigid: np.ndarray) -> np.ndarray:
    """max(rigid, Gaussian blur) with scipy (zero padding, kernel truncated at 3 sigma)."""
    blurred = ndimage.gaussian_filter(rigid, SIGMA_PX, mode="constant", cval=0.0, truncate=3.0)
    return np.maximum(rigid, blurred)


# A pixel-centre sphere centre makes the first contact exactly at r = 0.
_X, _Y = _grid()
CASES = [
    # R, x0, y0 (pixel centre), z0, depth
    (6.0, _X[0, 80], _Y[60, 0], 7.0, 1.0),
    (6.0, _X[0, 50], _Y[40, 0], 9.5, 0.5),
    (12.0, _X[0, 90], _Y[70, 0], 15.0, 1.5),
]


@pytest.mark.parametrize("R,x0,y0,z0,depth", CASES)
def test_press_sphere_cap(R, x0, y0, z0, depth):
    distances, hit, r2 = _sphere_distances(R, x0, y0, z0)
    contact = _press_jit(SPEC, jnp.asarray(distances, jnp.float32), jnp.asarray(hit), jnp.float32(depth))
    cap = _cap(R, depth, r2)
    rigid = np.asarray(contact.rigid_heightmap)
    assert _rmse(rigid, cap) < 0.01
    np.testing.assert_allclose(rigid, cap, atol=2e-5)  # float32 of the same closed form
    np.testing.assert_allclose(float(contact.travel), z0 - R + depth, atol=1e-5)
    assert bool(contact.touched)
    # Contact radius a = sqrt(2 R d - d^2) vs the mask's equivalent radius, within a pixel.
    mask = np.asarray(contact.mask)
    np.testing.assert_array_equal(mask, cap > MIN_INDENTATION_MM)
    a = np.sqrt(2 * R * depth - depth**2)
    a_mask = np.sqrt(mask.sum() * PX**2 / np.pi)
    assert abs(a - a_mask) < PX, (a, a_mask)


@pytest.mark.parametrize("R,x0,y0,z0,depth", CASES)
def test_gel_surface_vs_scipy_and_bounds(R, x0, y0, z0, depth):
    distances, hit, r2 = _sphere_distances(R, x0, y0, z0)
    contact = _press_jit(SPEC, jnp.asarray(distances, jnp.float32), jnp.asarray(hit), jnp.float32(depth))
    rigid = np.asarray(contact.rigid_heightmap, np.float64)
    gel = np.asarray(contact.heightmap, np.float64)
    mask = np.asarray(contact.mask)
    # The model, against an independent blur (scipy), everywhere.
    np.testing.assert_allclose(gel, _reference_gel(rigid), atol=2e-5)
    # Non-penetration: the gel is never less indented than the rigid object.
    assert np.all(gel >= rigid - 1e-6)
    # Away from the patch border (> 2 sigma inside), the gel conforms exactly to the object.
    square = np.ones((3, 3), bool)
    interior = ndimage.binary_erosion(mask, square, iterations=int(np.ceil(2 * SIGMA_PX)))
    assert interior.sum() > 20
    np.testing.assert_allclose(gel[interior], rigid[interior], atol=1e-5)
    # Outside the mask: a smooth skirt, positive next to the patch and zero beyond the
    # kernel's reach (3 sigma, square support of the separable kernel).
    ring = ndimage.binary_dilation(mask, square, iterations=2) & ~mask
    assert np.all(gel[ring] > 1e-3)
    far = ~ndimage.binary_dilation(mask, square, iterations=int(np.ceil(3 * SIGMA_PX)))
    np.testing.assert_allclose(gel[far], 0.0, atol=1e-6)
    # Smooth: away from the patch, slopes stay below the object's slope at the patch edge.
    outside = ~mask
    dy, dx = np.gradient(gel, PX)
    edge_slope = np.sqrt(2 * R * depth - depth**2) / (R - depth)
    assert np.max(np.hypot(dx, dy)[outside]) <= edge_slope * 1.05


def test_gel_sags_at_most_a_little_inside_the_patch_edge():
    # Documented in tactojax/sensor/_contact.py: within ~2 sigma of the patch edge the smoothed
    # membrane may lie below the object's surface, by at most ~0.1 mm for a 1 mm press.
    R, x0, y0, z0, depth = CASES[0]
    distances, hit, _ = _sphere_distances(R, x0, y0, z0)
    contact = _press_jit(SPEC, jnp.asarray(distances, jnp.float32), jnp.asarray(hit), jnp.float32(depth))
    mask = np.asarray(contact.mask)
    gap = np.asarray(contact.heightmap)[mask] - np.asarray(contact.rigid_heightmap)[mask]
    assert gap.min() >= 0.0
    assert gap.max() <= 0.12 * depth


def test_press_nothing_hit():
    contact = _press_jit(SPEC, jnp.full((H, W), 3.0), jnp.zeros((H, W), bool), jnp.float32(1.0))
    assert not bool(contact.touched)
    np.testing.assert_array_equal(np.asarray(contact.heightmap), 0.0)
    np.testing.assert_array_equal(np.asarray(contact.rigid_heightmap), 0.0)
    assert not np.any(np.asarray(contact.mask))


def test_press_vmap_matches_loop():
    batch = [_sphere_distances(R, x0, y0, z0) for R, x0, y0, z0, _ in CASES]
    distances = jnp.asarray(np.stack([b[0] for b in batch]), jnp.float32)
    hit = jnp.asarray(np.stack([b[1] for b in batch]))
    depths = jnp.asarray([c[4] for c in CASES], jnp.float32)
    batched = jax.jit(jax.vmap(press, in_axes=(None, 0, 0, 0)))(SPEC, distances, hit, depths)
    for i in range(len(CASES)):
        single = _press_jit(SPEC, distances[i], hit[i], depths[i])
        np.testing.assert_allclose(np.asarray(batched.heightmap[i]), np.asarray(single.heightmap), atol=1e-6)
        np.testing.assert_array_equal(np.asarray(batched.mask[i]), np.asarray(single.mask))


# ---------------------------------------------------------------- the simulator's full path

def _from_above(x: float, y: float, height: float) -> jaxlie.SE3:
    """Sensor pose in the object frame: gel at `height` above the origin, its +z along -z_object."""
    return jaxlie.SE3.from_rotation_and_translation(
        jaxlie.SO3.from_x_radians(jnp.pi), jnp.asarray([x, y, height], jnp.float32))


def _stack(poses: list[jaxlie.SE3]) -> jaxlie.SE3:
    return jax.tree.map(lambda *xs: jnp.stack(xs), *poses)


def test_touch_sphere_matches_cap():
    obj = get_object("calib_sphere")
    R = 6.0
    assert obj.parameters["radius_mm"] == R
    # Two jaws: centred, and offset by (1, -2) mm in the object frame.
    offsets = [(0.0, 0.0), (1.0, -2.0)]
    depths = np.array([1.0, 0.6])
    T = _stack([_from_above(ox, oy, 8.0) for ox, oy in offsets])
    contact, images, collides = touch(jax.random.key(0), SPEC, obj, T, jnp.asarray(depths, jnp.float32),
                                      max_distance=20.0)
    assert not np.any(np.asarray(collides))
    assert images.shape == (2, H, W, 3)
    x, y = _grid()
    for i, ((ox, oy), depth) in enumerate(zip(offsets, depths)):
        # Sensor frame = object frame turned by pi about x: the sphere centre, at the object
        # origin, sits at sensor (x, y) = (-ox, +oy), 8 mm ahead along sensor +z.
        r2 = (x + ox) ** 2 + (y - oy) ** 2
        cap = _cap(R, depth, r2)
        rigid = np.asarray(contact.rigid_heightmap[i])
        assert _rmse(rigid, cap) < 0.01, _rmse(rigid, cap)
        # The pixel grid misses the exact apex by < 1 px: the cap is off by at most r^2 / 2R.
        np.testing.assert_allclose(rigid, cap, atol=PX**2 / (2 * R) + 1e-4)
        # Travel: 8 - 6 = 2 mm to first contact (up to the apex sampling), plus the depth.
        np.testing.assert_allclose(float(contact.travel[i]), 2.0 + depth, atol=PX**2 / R)
        a = np.sqrt(2 * R * depth - depth**2)
        assert abs(a - np.sqrt(np.asarray(contact.mask[i]).sum() * PX**2 / np.pi)) < PX
        gel = np.asarray(contact.heightmap[i], np.float64)
        assert np.all(gel >= rigid - 1e-6)
        np.testing.assert_allclose(gel, _reference_gel(rigid.astype(np.float64)), atol=2e-5)


def test_touch_flat_face_uniform_indentation():
    obj = get_object("cuboid")  # Box, half extents (40, 10, 12.5): top face at z = 12.5
    half = obj.bounds[1]
    depth = 0.8
    T = _stack([_from_above(0.0, 0.0, 20.0), _from_above(3.0, 5.0, 20.0)])
    contact, _, collides = touch(jax.random.key(1), SPEC, obj, T, jnp.asarray([depth, depth], jnp.float32),
                                 max_distance=30.0)
    assert not np.any(np.asarray(collides))
    x, y = _grid()
    for i, (ox, oy) in enumerate([(0.0, 0.0), (3.0, 5.0)]):
        # Object (x, y) under sensor pixel (x, y): (ox + x, oy - y).
        on_face = (np.abs(ox + x) <= half[0]) & (np.abs(oy - y) <= half[1])
        rigid = np.asarray(contact.rigid_heightmap[i])
        mask = np.asarray(contact.mask[i])
        np.testing.assert_array_equal(mask, on_face)
        np.testing.assert_allclose(rigid[mask], depth, atol=1e-5)
        np.testing.assert_array_equal(rigid[~mask], 0.0)
        np.testing.assert_allclose(float(contact.travel[i]), 20.0 - half[2] + depth, atol=1e-5)


def test_touch_nothing_hit():
    obj = get_object("calib_sphere")
    # Facing away from the sphere (+z of the object frame), and beside it.
    away = jaxlie.SE3.from_translation(jnp.asarray([0.0, 0.0, 8.0], jnp.float32))
    beside = _from_above(30.0, 0.0, 8.0)
    contact, _, collides = touch(jax.random.key(2), SPEC, obj, _stack([away, beside]),
                                 jnp.asarray([1.0, 1.0], jnp.float32), max_distance=20.0)
    np.testing.assert_array_equal(np.asarray(contact.touched), [False, False])
    np.testing.assert_array_equal(np.asarray(contact.heightmap), 0.0)
    np.testing.assert_array_equal(np.asarray(contact.rigid_heightmap), 0.0)
    assert not np.any(np.asarray(contact.mask))
    assert not np.any(np.asarray(collides))


def test_gel_surface_direct_matches_scipy():
    """gel_surface on an arbitrary non-negative field (a ring), against scipy."""
    x, y = _grid()
    r = np.hypot(x - 2.0, y + 1.0)
    rigid = np.maximum(0.0, 0.5 - 2.0 * np.abs(r - 4.0))
    gel = np.asarray(jax.jit(gel_surface)(SPEC, jnp.asarray(rigid, jnp.float32)), np.float64)
    np.testing.assert_allclose(gel, _reference_gel(rigid), atol=2e-5)
    # The narrow cavity inside the ring is bridged: positive inside the ring's hole near it.
    assert gel[np.abs(r - 3.3) < 0.1].min() > 0.01
