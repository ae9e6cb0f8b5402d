"""ICP: recovery of known perturbations, GN vs LM, vmap vs loop, failure modes, gradients."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
from jax.test_util import check_grads

from tactojax.localize import Touch
from tactojax.localize.baselines import IcpSettings
from tactojax.localize._evaluate import cloud_rmse
from tactojax.localize._icp import icp
from tactojax.localize._points import contact_points

CANDIDATES = jnp.array([6, 7, 8, 11, 12, 13, 16, 17])
"""The map imprints around the object origin (the touch lies among them)."""

_icp = jax.jit(icp, static_argnums=6)
"""One compilation per setting, shared by the tests."""
SETTINGS = {solver: IcpSettings(iterations=30, solver=solver) for solver in ("gauss-newton", "levenberg-marquardt")}


def _touch(synthetic, T_true):
    heightmap, mask = synthetic.render(synthetic.bumps, T_true)
    return Touch(heightmap=jnp.asarray(heightmap), mask=jnp.asarray(mask), feature=jnp.zeros(48),
                 opening=jnp.float32(20.0))


def _perturb(T, translation, rotation_deg):
    delta = jaxlie.SE3.from_rotation_and_translation(
        jaxlie.SO3.exp(jnp.deg2rad(jnp.asarray(rotation_deg, jnp.float32))), jnp.asarray(translation, jnp.float32))
    return delta @ T


@pytest.fixture(scope="module")
def problem(bumps_view, synthetic):
    view = bumps_view
    T_true = synthetic.sensor_pose(1.3, -0.7, 5.0)  # between the map's presses
    points, valid = contact_points(_touch(synthetic, T_true), view.mm_per_px, 128)
    return view, T_true, points, valid


@pytest.mark.parametrize("solver", ["gauss-newton", "levenberg-marquardt"])
@pytest.mark.parametrize("translation, rotation_deg", [((1.5, -1.0, 0.4), (2.0, -1.5, 3.0)),
                                                       ((-0.8, 1.2, -0.3), (-3.0, 2.0, -4.0))])
def test_icp_recovers_a_known_perturbation(problem, solver, translation, rotation_deg):
    view, T_true, points, valid = problem
    start = _perturb(T_true, translation, rotation_deg)
    estimate = _icp(view, CANDIDATES, jnp.ones(8, bool), points, valid, start, SETTINGS[solver])
    assert float(cloud_rmse(points, valid, T_true, start)) > 1.0
    assert float(cloud_rmse(points, valid, T_true, estimate.T_object_sensor)) < 0.05
    assert bool(estimate.converged) and float(estimate.overlap) > 0.9 and float(estimate.score) < 0.02
    assert 1 < int(estimate.iterations) < 30


def test_gauss_newton_and_levenberg_marquardt_agree(problem):
    view, T_true, points, valid = problem
    start = _perturb(T_true, (1.0, 0.5, -0.2), (1.0, 2.0, -2.0))
    run = lambda solver: _icp(view, CANDIDATES, jnp.ones(8, bool), points, valid, start, SETTINGS[solver])  # noqa: E731
    gn, lm = run("gauss-newton"), run("levenberg-marquardt")
    assert float(cloud_rmse(points, valid, gn.T_object_sensor, lm.T_object_sensor)) < 0.02


def test_vmapped_icp_matches_a_python_loop(problem):
    view, T_true, points, valid = problem
    starts = [_perturb(T_true, (0.3 * i, -0.2 * i, 0.1), (i, -i, 2.0 * i)) for i in range(3)]
    settings = SETTINGS["gauss-newton"]
    batched = jax.jit(jax.vmap(icp, in_axes=(None, None, None, None, None, 0, None)), static_argnums=6)(
        view, CANDIDATES, jnp.ones(8, bool), points, valid, jax.tree.map(lambda *x: jnp.stack(x), *starts), settings)
    for i, start in enumerate(starts):
        one = _icp(view, CANDIDATES, jnp.ones(8, bool), points, valid, start, settings)
        np.testing.assert_allclose(np.asarray(batched.T_object_sensor.wxyz_xyz[i]),
                                   np.asarray(one.T_object_sensor.wxyz_xyz), atol=2e-5)
        assert int(batched.iterations[i]) == int(one.iterations)


def test_no_points_or_no_candidates_fail_without_nan(problem):
    view, T_true, points, valid = problem
    start = _perturb(T_true, (1.0, 0.0, 0.0), (0.0, 0.0, 5.0))
    run = lambda *args: _icp(*args, SETTINGS["gauss-newton"])  # noqa: E731
    for point_valid, candidate_valid in [(jnp.zeros_like(valid), jnp.ones(8, bool)),
                                         (valid, jnp.zeros(8, bool))]:
        estimate = run(view, CANDIDATES, candidate_valid, points, point_valid, start)
        assert not bool(estimate.converged)
        assert np.all(np.isfinite(np.asarray(estimate.T_object_sensor.wxyz_xyz)))
        np.testing.assert_allclose(np.asarray(estimate.T_object_sensor.wxyz_xyz), np.asarray(start.wxyz_xyz), atol=1e-6)
        assert np.isfinite(float(estimate.score)) and float(estimate.overlap) == 0.0
    # A start far away from every candidate: nothing matches, the start comes back.
    far = _perturb(T_true, (0.0, 0.0, 50.0), (0.0, 0.0, 0.0))
    estimate = run(view, CANDIDATES, jnp.ones(8, bool), points, valid, far)
    assert not bool(estimate.converged)
    np.testing.assert_allclose(np.asarray(estimate.T_object_sensor.wxyz_xyz), np.asarray(far.wxyz_xyz), atol=1e-6)


def test_gradient_of_the_pose_with_respect_to_the_touch_heightmap(bumps_view, synthetic):
    with jax.enable_x64(True):
        view = jax.tree.map(lambda x: x.astype(jnp.float64) if jnp.issubdtype(x.dtype, jnp.floating) else x,
                            bumps_view)
        T_true = jaxlie.SE3(synthetic.sensor_pose(1.3, -0.7, 5.0).wxyz_xyz.astype(jnp.float64))
        touch = _touch(synthetic, T_true)
        start = jaxlie.SE3(_perturb(T_true, (0.4, -0.3, 0.2), (1.0, -1.0, 2.0)).wxyz_xyz.astype(jnp.float64))
        # Smooth settings: no trimming, no freezing (a finite difference must not change the
        # set of used points or the iteration that converges).
        settings = IcpSettings(iterations=5, trim_fraction=1.0, tolerance_mm=0.0, max_distance_mm=3.0)

        @jax.jit  # the map is an argument, not a constant folded into the compiled program
        def pose_in(view, heightmap):
            points, valid = contact_points(touch.replace(heightmap=heightmap), view.mm_per_px, 48)
            estimate = icp(view, CANDIDATES, jnp.ones(8, bool), points, valid, start, settings)
            return estimate.T_object_sensor.log()

        pose = lambda heightmap: pose_in(view, heightmap)  # noqa: E731
        heightmap = touch.heightmap.astype(jnp.float64)
        # ICP is smooth between changes of correspondence; a small step (float64) keeps the finite
        # difference inside one smooth piece (eps 1e-5 straddled a kink at 1 in 5 touch positions).
        check_grads(pose, (heightmap,), order=1, modes=["rev"], eps=1e-7, atol=1e-4, rtol=1e-3)
        # Raising the whole patch by 0.1 mm moves the estimate by about 0.1 mm along the sensor z.
        moved = pose(heightmap + 0.1 * touch.mask)
        T0, T1 = jaxlie.SE3.exp(pose(heightmap)), jaxlie.SE3.exp(moved)
        shift = (T0.inverse() @ T1).translation()
        np.testing.assert_allclose(np.asarray(shift), [0.0, 0.0, 0.1], atol=0.02)


def test_positive_definite_solve_matches_numpy_with_its_derivatives():
    from tactojax.localize._solvers import solve_positive_definite

    rng = np.random.default_rng(0)
    matrix = rng.normal(size=(6, 6))
    matrix = matrix @ matrix.T + 0.1 * np.eye(6)
    vector = rng.normal(size=6)
    with jax.enable_x64(True):
        solve = jax.jit(lambda a, b: solve_positive_definite(0.5 * (a + a.T), b))
        np.testing.assert_allclose(np.asarray(solve(matrix, vector)), np.linalg.solve(matrix, vector), rtol=1e-9)
        check_grads(solve, (jnp.asarray(matrix), jnp.asarray(vector)), order=1, modes=["fwd", "rev"])


def test_per_point_candidates_register_as_shared_ones(problem):
    """Every point given the same candidate row: the same fit as shared candidates (which copy
    the candidates' surfaces, where per-point ones look up the map itself)."""
    view, T_true, points, valid = problem
    start = _perturb(T_true, (0.8, -0.5, 0.2), (1.0, -1.0, 2.0))
    settings = SETTINGS["gauss-newton"]
    shared = _icp(view, CANDIDATES, jnp.ones(8, bool), points, valid, start, settings)
    rows = jnp.broadcast_to(CANDIDATES, (points.shape[0], 8))
    per_point = _icp(view, rows, jnp.ones(rows.shape, bool), points, valid, start, settings)
    assert float(cloud_rmse(points, valid, shared.T_object_sensor, per_point.T_object_sensor)) < 1e-3
    np.testing.assert_allclose(float(per_point.score), float(shared.score), atol=1e-5)
    assert float(cloud_rmse(points, valid, T_true, per_point.T_object_sensor)) < 0.05


def test_blocks_past_the_active_ones_are_never_read(problem):
    """Points in blocks (a belief's touches): with only the first blocks active, the fit equals
    the one where the other blocks' points are masked out; their points, though marked valid
    (and 0.6 mm off the first block's, so that they would pull the fit), are never matched."""
    view, T_true, points, valid = problem
    start = _perturb(T_true, (0.8, -0.5, 0.2), (1.0, -1.0, 2.0))
    settings = SETTINGS["gauss-newton"]
    rows = jnp.broadcast_to(CANDIDATES, (2 * points.shape[0], 8))
    shifted = jnp.concatenate([points, points + jnp.array([0.6, 0.0, 0.0])])
    masked = _icp(view, rows, jnp.ones(rows.shape, bool), shifted, jnp.concatenate([valid, jnp.zeros_like(valid)]),
                  start, settings)
    blocked = jax.jit(icp, static_argnums=6, static_argnames=("blocks",))(
        view, rows, jnp.ones(rows.shape, bool), shifted, jnp.concatenate([valid, valid]), start, settings, blocks=2,
        active_blocks=jnp.int32(1))
    assert float(cloud_rmse(points, valid, masked.T_object_sensor, blocked.T_object_sensor)) < 1e-3
    np.testing.assert_allclose(float(blocked.score), float(masked.score), atol=1e-5)
    assert bool(blocked.converged) == bool(masked.converged)
    assert float(cloud_rmse(points, valid, T_true, blocked.T_object_sensor)) < 0.05


def test_the_nearest_association_refuses_per_point_candidates_and_blocks(problem):
    """The nearest association registers every point against one shared set of imprints: per-point
    candidates or blocks of points are a clear error, not a silently wrong fit."""
    view, T_true, points, valid = problem
    settings = IcpSettings(iterations=2, association="nearest")
    rows = jnp.broadcast_to(CANDIDATES, (points.shape[0], 8))
    with pytest.raises(ValueError, match="need the projective association"):
        icp(view, rows, jnp.ones(rows.shape, bool), points, valid, T_true, settings)
    with pytest.raises(ValueError, match="need the projective association"):
        icp(view, CANDIDATES, jnp.ones(8, bool), points, valid, T_true, settings, blocks=1, active_blocks=jnp.int32(1))
