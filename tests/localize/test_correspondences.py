"""Projective and nearest-point correspondences against a numpy reference."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax.localize._correspondences import find_correspondences, nearest_correspondences, surface_lookup
from tactojax.mapping import pack_heightmaps


def _bilinear_numpy(heightmap, mask, x, y, mm_per_px):
    height_px, width_px = heightmap.shape
    col, row = x / mm_per_px + (width_px - 1) / 2, y / mm_per_px + (height_px - 1) / 2
    if not (0 <= col <= width_px - 1 and 0 <= row <= height_px - 1):
        return None
    c0, r0 = min(int(np.floor(col)), width_px - 2), min(int(np.floor(row)), height_px - 2)
    fc, fr = col - c0, row - r0
    h = heightmap[r0:r0 + 2, c0:c0 + 2].astype(np.float64)
    value = (h[0, 0] * (1 - fc) * (1 - fr) + h[0, 1] * fc * (1 - fr) + h[1, 0] * (1 - fc) * fr + h[1, 1] * fc * fr)
    slope_x = ((h[0, 1] - h[0, 0]) * (1 - fr) + (h[1, 1] - h[1, 0]) * fr) / mm_per_px
    slope_y = ((h[1, 0] - h[0, 0]) * (1 - fc) + (h[1, 1] - h[0, 1]) * fc) / mm_per_px
    return value, np.array([slope_x, slope_y]), bool(mask[r0:r0 + 2, c0:c0 + 2].all())


def test_surface_lookup_matches_numpy():
    rng = np.random.default_rng(0)
    # Heights that float16 holds exactly (multiples of 2^-10 below 1 mm), packed with the masks.
    heightmaps = (rng.integers(0, 1024, (3, 6, 8)) / 1024).astype(np.float32)
    masks = rng.uniform(size=(3, 6, 8)) > 0.2
    imprint = rng.integers(0, 3, 200)
    points = np.concatenate([rng.uniform(-2.5, 2.5, (200, 1)), rng.uniform(-1.8, 1.8, (200, 1)),
                             rng.normal(size=(200, 1))], axis=1).astype(np.float32)
    packed = pack_heightmaps(heightmaps, masks)
    height, slope, contact = jax.jit(surface_lookup, static_argnums=3)(packed, imprint, points, 0.5)
    checked = 0
    for i in range(200):
        reference = _bilinear_numpy(heightmaps[imprint[i]], masks[imprint[i]], points[i, 0], points[i, 1], 0.5)
        if reference is None:  # outside the image
            assert not bool(contact[i])
            continue
        checked += 1
        np.testing.assert_allclose(float(height[i]), reference[0], atol=1e-5)
        np.testing.assert_allclose(np.asarray(slope[i]), reference[1], atol=1e-4)
        assert bool(contact[i]) == reference[2]
    assert checked > 100


def test_find_correspondences_matches_a_loop(bumps_map, bumps_view):
    view = bumps_view
    candidates = jnp.array([6, 7, 11, 12])
    candidate_valid = jnp.array([True, True, False, True])
    # Imprint 13's points plus noise (sub-pixel along x, y: the presses' pixel grids coincide,
    # and exactly on a pixel edge the slope of either cell is right).
    rng = np.random.default_rng(1)
    points = np.asarray(bumps_map.points_object[13]) + rng.normal(0, 1, (128, 3)) * np.array([0.1, 0.1, 0.5])
    points_valid = np.asarray(bumps_map.valid[13])
    matches = jax.jit(find_correspondences, static_argnums=5)(
        view, candidates, candidate_valid, jnp.asarray(points, jnp.float32), jnp.asarray(points_valid), 1.0)
    heightmaps, masks = np.asarray(bumps_map.heightmaps), np.asarray(bumps_map.masks)
    matrices = np.asarray(bumps_map.T_object_sensor.as_matrix(), np.float64)
    for p in range(128):
        found = {}  # slot -> (residual, target, normal)
        for slot, k in enumerate(np.asarray(candidates)):
            if not candidate_valid[slot] or not points_valid[p]:
                continue
            inverse = np.linalg.inv(matrices[k])
            q = inverse[:3, :3] @ points[p] + inverse[:3, 3]
            reference = _bilinear_numpy(heightmaps[k], masks[k], q[0], q[1], view.mm_per_px)
            if reference is None or not reference[2]:
                continue
            normal = np.array([-reference[1][0], -reference[1][1], -1.0])
            normal /= np.linalg.norm(normal)
            residual = normal[2] * (q[2] + reference[0])
            if abs(residual) <= 1.0:
                target = matrices[k][:3, :3] @ np.array([q[0], q[1], -reference[0]]) + matrices[k][:3, 3]
                found[slot] = (residual, target, matrices[k][:3, :3] @ normal)
        assert bool(matches.valid[p]) == bool(found)
        if found:
            # The chosen candidate is one with the smallest |residual| (the presses agree to
            # rounding where they overlap, so ties are broken by float noise).
            slot = int(matches.candidate[p])
            assert slot in found
            assert abs(found[slot][0]) <= min(abs(r) for r, _, _ in found.values()) + 1e-4
            np.testing.assert_allclose(float(matches.residual[p]), found[slot][0], atol=2e-4)
            np.testing.assert_allclose(np.asarray(matches.target[p]), found[slot][1], atol=2e-4)
            np.testing.assert_allclose(np.asarray(matches.normal[p]), found[slot][2], atol=2e-4)
    assert int(matches.valid.sum()) > 50


def test_residual_is_the_distance_along_the_normal_on_a_plane(bumps_map, bumps_view):
    # A flat heightmap h = 0.5: the surface is the plane z_sensor = -0.5 (correspondences read
    # the stored heightmaps, not the map's surface).
    view = bumps_view.replace(packed_heightmaps=jnp.full_like(bumps_view.packed_heightmaps, 0.5))
    T = jax.tree.map(lambda x: x[12], bumps_map.T_object_sensor)
    p_sensor = jnp.array([[1.0, 2.0, -0.5 + 0.3], [0.0, 0.0, -0.5 - 0.2]])
    matches = jax.jit(find_correspondences, static_argnums=5)(
        view, jnp.array([12]), jnp.array([True]), T @ p_sensor, jnp.ones(2, bool), 5.0)
    # The normal points towards -z_sensor, out of the object: a point inside the object (towards
    # +z_sensor) has a negative residual.
    np.testing.assert_allclose(np.asarray(matches.residual), [-0.3, 0.2], atol=1e-5)
    np.testing.assert_allclose(np.asarray(T.inverse() @ matches.target)[:, 2], [-0.5, -0.5], atol=1e-5)
    assert isinstance(T, jaxlie.SE3)


def test_per_point_candidates_match_each_row_shared(bumps_map, bumps_view):
    """(P, N) candidates: every point is matched exactly as if its own row were shared by all."""
    view = bumps_view
    rows = (jnp.array([6, 7, 11, 12]), jnp.array([12, 13, 17, 18]))
    rows_valid = (jnp.array([True, True, False, True]), jnp.array([True, True, True, True]))
    rng = np.random.default_rng(2)
    points = np.asarray(bumps_map.points_object[12]) + rng.normal(0, 1, (128, 3)) * np.array([0.1, 0.1, 0.5])
    points = jnp.asarray(points, jnp.float32)
    points_valid = jnp.asarray(bumps_map.valid[12])
    row_of_point = np.arange(128) % 2
    per_point = jax.jit(find_correspondences, static_argnums=5)(
        view, jnp.stack(rows)[row_of_point], jnp.stack(rows_valid)[row_of_point], points, points_valid, 1.0)
    for row in range(2):
        shared = jax.jit(find_correspondences, static_argnums=5)(view, rows[row], rows_valid[row], points,
                                                                 points_valid, 1.0)
        mine = row_of_point == row
        np.testing.assert_array_equal(np.asarray(per_point.valid)[mine], np.asarray(shared.valid)[mine])
        found = np.asarray(shared.valid) & mine
        assert found.sum() > 20
        np.testing.assert_array_equal(np.asarray(per_point.candidate)[found], np.asarray(shared.candidate)[found])
        for field in ("residual", "target", "normal"):
            np.testing.assert_allclose(np.asarray(getattr(per_point, field))[found],
                                       np.asarray(getattr(shared, field))[found], atol=1e-5)


def test_nearest_correspondences_match_numpy(bumps_map, bumps_view):
    view = bumps_view
    rng = np.random.default_rng(0)
    points = np.asarray(bumps_map.points_object[12, :40]) + rng.normal(0, 0.3, (40, 3))
    candidates, candidate_valid = jnp.array([7, 12, 13]), jnp.array([True, False, True])
    matches = jax.jit(nearest_correspondences, static_argnums=5)(
        view, candidates, candidate_valid, jnp.asarray(points, jnp.float32), jnp.ones(40, bool), 1.0)
    targets = np.asarray(view.points)[[7, 13]].reshape(-1, 3)
    normals = np.asarray(view.normals)[[7, 13]].reshape(-1, 3)
    target_valid = np.asarray(view.points_valid)[[7, 13]].reshape(-1)
    for p in range(40):
        distance = np.where(target_valid, np.linalg.norm(targets - points[p], axis=1), np.inf)
        j = int(np.argmin(distance))
        assert bool(matches.valid[p]) == (distance[j] <= 1.0)
        np.testing.assert_allclose(np.asarray(matches.target[p]), targets[j], atol=1e-5)
        np.testing.assert_allclose(float(matches.residual[p]), normals[j] @ (points[p] - targets[j]), atol=1e-4)
        # The match's candidate holds the target (imprints 7 and 13 may hold the same point).
        half = targets.shape[0] // 2
        held = targets[:half] if int(matches.candidate[p]) == 0 else targets[half:]
        assert int(matches.candidate[p]) in (0, 2)
        assert np.min(np.linalg.norm(held - targets[j], axis=1)) < 1e-5


def test_matvec_matches_matmul_and_refuses_other_shapes():
    import jax.numpy as jnp

    from tactojax.localize._correspondences import matvec

    rng = np.random.default_rng(0)
    matrix, vector = rng.normal(size=(4, 3, 3)), rng.normal(size=(5, 4, 3))
    np.testing.assert_allclose(np.asarray(matvec(jnp.asarray(matrix), jnp.asarray(vector))),
                               np.einsum("bij,nbj->nbi", matrix, vector), rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match="3, 3"):
        matvec(jnp.zeros((3, 2)), jnp.zeros(2))
