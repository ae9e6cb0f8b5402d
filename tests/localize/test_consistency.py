"""Consistency checks (the true pose agrees, a wrong one violates); nearest-point correspondences."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.localize import LocalizationMap, Query, SearchSettings, consistency, query_points, verification_score
from tactojax.localize._correspondences import nearest_correspondences


def test_true_pose_agrees_and_wrong_poses_do_not(bumps_map, synthetic):
    view = LocalizationMap.from_tactile_map(bumps_map)
    T_true = synthetic.sensor_pose(1.3, -0.7, 5.0)
    heightmap, mask = synthetic.render(synthetic.bumps, T_true)
    query = Query(heightmap=jnp.asarray(heightmap), mask=jnp.asarray(mask), feature=jnp.zeros(48),
                  opening=jnp.float32(20.0))
    points, valid = query_points(query, view.mm_per_px, 96)
    candidates = jnp.array([6, 7, 8, 11, 12, 13, 16, 17])
    check = jax.jit(lambda T: consistency(view, candidates, jnp.ones(8, bool), query.heightmap, query.mask,
                                          points, valid, T))
    true = check(T_true)
    assert float(true.agreement) > 0.85 and float(true.reverse_agreement) > 0.5
    assert float(true.violation) == 0.0 and float(true.reverse_violation) == 0.0
    # Slid by 3 mm: the map's contact next to the patch reaches into the query's gel where it felt
    # nothing (and the patch into theirs).
    slid = check(T_true @ jaxlie.SE3.from_translation(jnp.array([3.0, 0.0, 0.0])))
    assert float(slid.violation + slid.reverse_violation) > 0.05
    assert float(slid.score()) < float(true.score()) - 0.5
    # 1 mm too deep: the surfaces no longer agree.
    deeper = check(T_true @ jaxlie.SE3.from_translation(jnp.array([0.0, 0.0, 1.0])))
    assert float(deeper.agreement) < 0.5 * float(true.agreement)


def test_verification_score_is_the_consistency_with_the_imprints_around_the_pose(bumps_map, synthetic):
    view = LocalizationMap.from_tactile_map(bumps_map)
    T_true = synthetic.sensor_pose(1.3, -0.7, 5.0)
    heightmap, mask = synthetic.render(synthetic.bumps, T_true)
    points, valid = query_points(Query(heightmap=jnp.asarray(heightmap), mask=jnp.asarray(mask),
                                       feature=jnp.zeros(48), opening=jnp.float32(20.0)), view.mm_per_px, 96)
    available = jnp.ones(len(view), bool).at[12].set(False)  # one imprint held out
    settings = SearchSettings(verify_neighbours=4, violation_weight=3.0)
    score = jax.jit(lambda T: verification_score(view, jnp.asarray(heightmap), jnp.asarray(mask), points, valid, T,
                                                 available, settings))

    # Reference: the four available imprints whose contact centres are nearest to the placed
    # query's centroid, found in NumPy.
    centres, points_np, valid_np = np.asarray(view.centres), np.asarray(points), np.asarray(valid)
    for T in (T_true, T_true @ jaxlie.SE3.from_translation(jnp.array([3.0, 0.0, 0.0]))):
        centroid = np.asarray(T @ jnp.asarray(points_np[valid_np].mean(axis=0)))
        distance = np.where(np.asarray(available), np.linalg.norm(centres - centroid, axis=1), np.inf)
        nearest = jnp.asarray(np.argsort(distance)[:4])
        check = consistency(view, nearest, jnp.ones(4, bool), jnp.asarray(heightmap), jnp.asarray(mask), points,
                            valid, T)
        expected = check.agreement - 3.0 * (check.violation + check.reverse_violation)
        np.testing.assert_allclose(score(T), expected, atol=1e-6)
    assert float(score(T_true)) > 0.85


def test_nearest_correspondences_match_numpy(bumps_map):
    view = LocalizationMap.from_tactile_map(bumps_map)
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
        assert int(matches.candidate[p]) == (0 if j < targets.shape[0] // 2 else 2)
