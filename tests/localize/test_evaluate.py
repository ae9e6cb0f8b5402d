"""Leave-one-out evaluation against a numpy reference; the belief's Table III; map-size study; oracle retrieval."""

import jax
import jaxlie
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tactojax.localize.evaluation import evaluate_localization, map_size_study
from tactojax.localize._evaluate import cloud_moments, moment_rmse
from tactojax.localize._retrieval import closest_imprints


def _matrices(T):
    wxyz_xyz = np.asarray(T.wxyz_xyz, np.float64).reshape(-1, 7)
    matrix = np.zeros((len(wxyz_xyz), 4, 4))
    matrix[:, :3, :3] = Rotation.from_quat(wxyz_xyz[:, [1, 2, 3, 0]]).as_matrix()
    matrix[:, :3, 3], matrix[:, 3, 3] = wxyz_xyz[:, 4:], 1.0
    return matrix


def _rmse(points, a, b):
    pa = points @ a[:3, :3].T + a[:3, 3]
    pb = points @ b[:3, :3].T + b[:3, 3]
    return np.sqrt(np.mean(np.sum((pa - pb) ** 2, axis=1)))


FLIP = jaxlie.SE3.from_rotation(jaxlie.SO3.from_z_radians(np.pi))  # a (false) symmetry about z
SYMMETRIES = jaxlie.SE3(np.stack([np.asarray(jaxlie.SE3.identity().wxyz_xyz), np.asarray(FLIP.wxyz_xyz)]))


@pytest.fixture(scope="module")
def cti_errors(bumps_map):
    return evaluate_localization(jax.random.key(0), bumps_map, ["random", "cti"], symmetries=SYMMETRIES,
                                 chunk_size=8), _matrices(FLIP)[0]


def test_leave_one_out_cti_errors_match_numpy(bumps_map, cti_errors):
    results, flip = cti_errors
    errors = results["cti"]
    matrices = _matrices(bumps_map.T_object_sensor)
    features, openings, valid = bumps_map.features, bumps_map.openings, bumps_map.imprint_valid
    assert errors.queries.tolist() == np.flatnonzero(np.asarray(valid)).tolist()
    for q, k in enumerate(errors.queries):
        j = int(closest_imprints(features, openings, valid, features[k], openings[k], 1, exclude=int(k))[0][0])
        assert errors.imprint_index[q] == j
        points = np.asarray(bumps_map.points[k], np.float64)[np.asarray(bumps_map.valid[k])]
        np.testing.assert_allclose(errors.rmse[q], _rmse(points, matrices[k], matrices[j]), rtol=1e-4, atol=1e-4)
        np.testing.assert_allclose(errors.translation[q], np.linalg.norm(matrices[k][:3, 3] - matrices[j][:3, 3]),
                                   rtol=1e-4, atol=1e-4)
        angle = Rotation.from_matrix(matrices[k][:3, :3].T @ matrices[j][:3, :3]).magnitude()
        np.testing.assert_allclose(errors.rotation[q], np.rad2deg(angle), atol=0.05)
        symmetric = min(_rmse(points, matrices[k], matrices[j]), _rmse(points, matrices[k], flip @ matrices[j]))
        np.testing.assert_allclose(errors.symmetric_rmse[q], symmetric, rtol=1e-4, atol=1e-4)


def test_moment_rmse_matches_the_cloud_for_a_batch_of_poses():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(200, 3)) * [9.0, 6.0, 1.0] + [4.0, -2.0, 30.0]
    valid = rng.random(200) > 0.25
    wxyz_xyz = np.concatenate([Rotation.random(7, random_state=4).as_quat()[:, [3, 0, 1, 2]],
                               rng.normal(size=(7, 3)) * 40.0], axis=1)
    poses = jaxlie.SE3(np.asarray(wxyz_xyz, np.float32))
    T_true = jaxlie.SE3(poses.wxyz_xyz[0])
    near = jaxlie.SE3.exp(np.array([0.01, 0.0, -0.02, 1e-3, 0.0, 2e-3], np.float32)) @ T_true  # tiny error
    matrices = _matrices(poses)
    errors = np.asarray(moment_rmse(*cloud_moments(points.astype(np.float32), valid), T_true, poses))
    expected = [_rmse(points[valid], matrices[0], matrix) for matrix in matrices]
    np.testing.assert_allclose(errors, expected, rtol=1e-4, atol=1e-3)
    assert errors[0] < 1e-3  # the same pose
    small = float(moment_rmse(*cloud_moments(points.astype(np.float32), valid), T_true, near))
    np.testing.assert_allclose(small, _rmse(points[valid], matrices[0], _matrices(near)[0]), rtol=2e-2)


def test_summary_and_histogram(cti_errors):
    results, _ = cti_errors
    for errors in results.values():
        summary = errors.summary()
        assert summary["queries"] == len(errors.rmse) == sum(summary["histogram"]["counts"])
        assert summary["rmse_mm"]["median"] == pytest.approx(float(np.median(errors.rmse)))
        assert len(summary["histogram"]["counts"]) == len(summary["histogram"]["edges_mm"])
    assert np.median(results["cti"].rmse) < np.median(results["random"].rmse)
    assert np.all(np.isnan(results["cti"].probability))  # a baseline has no belief


def test_oracle_retrieval_is_the_truly_nearest_imprint(bumps_map, cti_errors):
    results, _ = cti_errors
    oracle = evaluate_localization(jax.random.key(0), bumps_map, ["cti"], oracle=True, chunk_size=8)["cti"]
    assert np.all(oracle.rmse <= results["cti"].rmse + 1e-4)
    matrices = _matrices(bumps_map.T_object_sensor)
    for q, k in enumerate(oracle.queries[:5]):
        points = np.asarray(bumps_map.points[k], np.float64)[np.asarray(bumps_map.valid[k])]
        best = min(_rmse(points, matrices[k], matrices[j]) for j in range(len(matrices)) if j != k)
        np.testing.assert_allclose(oracle.rmse[q], best, rtol=1e-4, atol=1e-4)


def test_map_size_study_queries_only_held_out_imprints(bumps_map):
    study = map_size_study(jax.random.key(1), bumps_map, ["cti"], fractions=(0.4, 1.0), chunk_size=8,
                           symmetries=SYMMETRIES)  # the same compiled evaluation as above
    part, full = study[0.4]["cti"], study[1.0]["cti"]
    assert len(full.queries) == 25 and len(part.queries) == 15
    in_map = np.setdiff1d(np.arange(25), part.queries)
    assert np.isin(part.imprint_index, in_map).all()


def test_table_iii_with_the_belief_on_a_tiny_map(bumps_map, belief_settings):
    """Leave-one-out with the belief (its queries held out of the map's surface, fold by fold)
    beside CTI-ICP-1: both localize the bumps' presses, the belief at least as well, with a
    probability for each."""
    results = evaluate_localization(jax.random.key(0), bumps_map, ("belief", "cti-icp-1"),
                                    symmetries=jaxlie.SE3.identity((1,)), pad_to_multiple=1,
                                    belief_settings=belief_settings, folds=3, chunk_size=4)
    belief, icp = results["belief"], results["cti-icp-1"]
    for errors in (belief, icp):
        assert errors.queries.tolist() == list(range(25)) and np.all(np.isfinite(errors.rmse))
        np.testing.assert_allclose(errors.symmetric_rmse, errors.rmse, rtol=1e-5, atol=1e-3)  # the identity alone
        assert errors.summary()["queries"] == 25
    assert np.all(belief.imprint_index == -1) and np.all(np.isnan(icp.probability))
    assert np.all((belief.probability >= 0.0) & (belief.probability <= 1.0 + 1e-6))
    assert np.median(belief.rmse) < 0.5 and np.median(belief.rmse) <= np.median(icp.rmse) + 0.05
    # The belief is confident where it is right: a query off by more than 2 mm never holds P > 0.9.
    assert not np.any((belief.rmse > 2.0) & (belief.probability > 0.9))


def test_the_leave_one_out_grid_reaches_a_whole_mapping_step():
    """A held-out imprint's nearest stored neighbours sit one step of the paper's mapping grid
    away (10 mm, 20 degrees of yaw); the new-grasps grid reaches half of it, the leave-one-out
    grid all of it, with as many candidates (offsets read back with scipy)."""
    import jax.numpy as jnp

    from tactojax.localize import BeliefSettings
    from tactojax.localize.evaluation import LEAVE_ONE_OUT_GRID

    def reach(grid):
        matrices = _matrices(grid.offsets(jnp.zeros(3)))
        shift = np.max(np.abs(matrices[:, :2, 3]))
        turn = np.max(Rotation.from_matrix(matrices[:, :3, :3]).magnitude())
        return shift, np.rad2deg(turn)

    default = BeliefSettings().grid
    assert LEAVE_ONE_OUT_GRID.size == default.size
    np.testing.assert_allclose(reach(default), (5.0, 10.0), atol=1e-4)
    np.testing.assert_allclose(reach(LEAVE_ONE_OUT_GRID), (10.0, 20.0), atol=1e-4)
