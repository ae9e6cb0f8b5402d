"""Table II shape fits on partial, noisy, displaced point clouds of the catalog objects, and the
least-squares solver against ``scipy.optimize.least_squares``.

* Clouds: points drawn uniformly over part of the catalog surface (the sides and only one end
  face; checked against the catalog's SDF), Gaussian noise of 0.05 mm, 3 % outliers displaced
  0.5 - 2 mm in random directions, a rigid transform (5 degrees and up to 5 mm as asked; then
  any rotation and up to 50 mm), and NaN padding rows marked invalid. Every Table II parameter
  must come back within 0.5 % of the catalog value (slopes: or 0.002 rad), the shape axis
  within 1 degree and the shape origin within 0.5 mm of the transform applied.
* Untouched sides: a cuboid cloud on two opposite sides and one end only; the other two sides
  go where the points on the touched ones stop (the least squares alone leaves them anywhere).
* Solver: an exponential-decay fit with outliers under each loss, against scipy's (float64)
  minimiser of the same robust cost; vmapped against a Python loop; failures as flags.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
import scipy.optimize

from tactojax.mapping._least_squares import solve_least_squares
from tactojax.mapping._shape_fit import (
    SHAPE_KINDS, TABLE2_PARAMETERS, ShapeFit, fit_shape, shape_fit_errors, true_shape_parameters,
)
from tactojax.objects import get_object

N_POINTS = 3000  # real points per cloud
N_PADDING = 72  # invalid rows (NaN), so that every cloud is (3072, 3): one compile per kind
NOISE_MM = 0.05
OUTLIER_FRACTION = 0.03
RELATIVE_TOLERANCE = 0.005
SLOPE_TOLERANCE_RAD = 0.002
AXIS_TOLERANCE_DEG = 1.0
ORIGIN_TOLERANCE_MM = 0.5

# (catalog object, shape kind, which end face is touched: -1 for -x, +1 for +x, seed). The
# catalog's wider / bigger end is at -x: the semicone's base face and the semipyramid's top face
# are left untouched, so their base sizes come from where the side points stop.
CASES = [
    ("cylinder", "cylinder", -1, 0),
    ("semicone", "semicone", +1, 1),
    ("double_cylinder", "double-cylinder", -1, 2),
    ("cuboid", "cuboid", +1, 3),
    ("semipyramid", "semipyramid", -1, 4),
]
SYMMETRIC_ENDS = ("cylinder", "cuboid")  # the shape frame's x axis is defined up to sign


def _profile(name: str):
    """The catalog object's cross-section along x (object frame, mm), from its parameters.

    Returns (half length, "round" or "square", half-width along y as a function of x, the same
    along z, taper d(half-width)/dx, step (x, small radius, big radius) or None).
    """
    obj = get_object(name)
    p = obj.parameters
    half_length = obj.extents[0] / 2
    if name == "cylinder":
        radius = lambda x: np.full_like(x, p["radius_mm"])  # noqa: E731
        return half_length, "round", radius, radius, 0.0, None
    if name == "semicone":  # base (wider) end at -x
        taper = -math.tan(p["slope_rad"])
        radius = lambda x: p["base_radius_mm"] + (x + half_length) * taper  # noqa: E731
        return half_length, "round", radius, radius, taper, None
    if name == "double_cylinder":  # big end at -x
        joint = -half_length + p["joint_mm"]
        radius = lambda x: np.where(x < joint, p["big_radius_mm"], p["small_radius_mm"])  # noqa: E731
        return half_length, "round", radius, radius, 0.0, (joint, p["small_radius_mm"], p["big_radius_mm"])
    if name == "cuboid":  # thinnest dimension along y
        return (half_length, "square", lambda x: np.full_like(x, p["side_2_mm"] / 2),
                lambda x: np.full_like(x, p["side_1_mm"] / 2), 0.0, None)
    if name == "semipyramid":  # base end at -x
        taper = -math.tan(p["slope_rad"])
        half_side = lambda x: p["base_side_mm"] / 2 + (x + half_length) * taper  # noqa: E731
        return half_length, "square", half_side, half_side, taper, None
    raise AssertionError(name)


def _surface_points(name: str, rng: np.random.Generator, touched_end: int) -> np.ndarray:
    """(N_POINTS, 3) points uniform over part of the object's surface (object frame, mm): the
    sides, the double-cylinder's step and the end face at ``touched_end`` (-1: -x, +1: +x)."""
    half_length, section, half_y, half_z, taper, step = _profile(name)
    slant = math.hypot(1.0, taper)  # area per unit length / perimeter

    def side(n):  # x by rejection on the local perimeter, then uniform around the section
        x = rng.uniform(-half_length, half_length, 20 * n)
        widths = half_y(x) + half_z(x)
        x = x[rng.uniform(0.0, widths.max(), len(x)) < widths][:n]
        a, b = half_y(x), half_z(x)
        if section == "round":
            angle = rng.uniform(0.0, 2 * np.pi, n)
            return np.stack([x, a * np.cos(angle), a * np.sin(angle)], axis=1)
        u = rng.uniform(0.0, 1.0, n) * 4 * (a + b)  # arc length around the rectangle
        edges = [u < 2 * a, u < 2 * a + 2 * b, u < 4 * a + 2 * b]
        y = np.select(edges, [-a + u, a, a - (u - 2 * a - 2 * b)], -a)
        z = np.select(edges, [-b, -b + (u - 2 * a), b], b - (u - 4 * a - 2 * b))
        return np.stack([x, y, z], axis=1)

    def annulus(n, x, inner, outer):  # uniform; a disk for inner = 0
        radius = np.sqrt(rng.uniform(inner**2, outer**2, n))
        angle = rng.uniform(0.0, 2 * np.pi, n)
        return np.stack([np.full(n, x), radius * np.cos(angle), radius * np.sin(angle)], axis=1)

    def rectangle(n, x, a, b):
        return np.stack([np.full(n, x), rng.uniform(-a, a, n), rng.uniform(-b, b, n)], axis=1)

    end = touched_end * half_length
    a_end, b_end = float(half_y(np.array(end))), float(half_z(np.array(end)))
    xs = np.linspace(-half_length, half_length, 100001)
    if section == "round":
        side_area = slant * 2 * np.pi * np.mean(half_y(xs)) * 2 * half_length
        parts = [(side_area, side), (np.pi * a_end**2, lambda n: annulus(n, end, 0.0, a_end))]
    else:
        side_area = slant * 4 * np.mean(half_y(xs) + half_z(xs)) * 2 * half_length
        parts = [(side_area, side), (4 * a_end * b_end, lambda n: rectangle(n, end, a_end, b_end))]
    if step is not None:
        joint, inner, outer = step
        parts.append((np.pi * (outer**2 - inner**2), lambda n: annulus(n, joint, inner, outer)))
    areas = np.array([area for area, _ in parts])
    counts = rng.multinomial(N_POINTS, areas / areas.sum())
    points = np.concatenate([sample(n) for (_, sample), n in zip(parts, counts)])
    # The catalog's own SDF agrees that these points lie on its surface.
    assert np.max(np.abs(np.asarray(get_object(name).solid.sdf(jnp.asarray(points, jnp.float32))))) < 1e-3
    return points[rng.permutation(N_POINTS)]


def _corrupt(points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Gaussian noise on every point, and outliers displaced 0.5 - 2 mm in random directions."""
    points = points + rng.normal(0.0, NOISE_MM, points.shape)
    n_outliers = int(OUTLIER_FRACTION * len(points))
    index = rng.choice(len(points), n_outliers, replace=False)
    direction = rng.normal(size=(n_outliers, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points[index] += direction * rng.uniform(0.5, 2.0, (n_outliers, 1))
    return points


def _random_pose(rng: np.random.Generator) -> jaxlie.SE3:
    """A rigid transform: 5 degrees about a random axis, up to 5 mm along each axis."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    rotation = jaxlie.SO3.exp(jnp.asarray(axis * math.radians(5.0), jnp.float32))
    return jaxlie.SE3.from_rotation_and_translation(rotation, jnp.asarray(rng.uniform(-5, 5, 3), jnp.float32))


def _cloud(name: str, touched_end: int, seed: int):
    """A displaced partial cloud with padding: points (3072, 3), valid (3072,), T_map_object."""
    rng = np.random.default_rng(seed)
    points = _corrupt(_surface_points(name, rng, touched_end), rng)
    T_map_object = _random_pose(rng)
    points = np.asarray(T_map_object @ jnp.asarray(points, jnp.float32))
    padded = np.concatenate([points, np.full((N_PADDING, 3), np.nan, np.float32)])
    valid = np.arange(len(padded)) < N_POINTS
    return padded, valid, T_map_object


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0)))


# ---------------------------------------------------------------- shape fits

@pytest.mark.parametrize("name, kind, touched_end, seed", CASES, ids=[case[1] for case in CASES])
def test_fit_recovers_catalog_parameters_and_pose(name, kind, touched_end, seed):
    points, valid, T_map_object = _cloud(name, touched_end, seed)
    fit = fit_shape(points, valid, kind)
    truth = true_shape_parameters(get_object(name), kind)

    assert fit.kind == kind
    assert bool(fit.converged)
    assert float(fit.inlier_fraction) > 0.95
    assert float(fit.rms_residual_mm) < 2 * NOISE_MM * math.sqrt(3)
    errors = shape_fit_errors(fit, truth)
    assert set(errors) == set(TABLE2_PARAMETERS[kind])
    for parameter, error in errors.items():
        if parameter == "slope_rad":
            assert (error["relative_error"] < RELATIVE_TOLERANCE
                    or abs(error["estimate"] - error["true"]) < SLOPE_TOLERANCE_RAD), (parameter, error)
        else:
            assert error["relative_error"] < RELATIVE_TOLERANCE, (parameter, error)
    # The nuisance length: the untouched end is where the side points stop.
    assert abs(float(fit.parameters["length_mm"]) - truth["length_mm"]) < 2 * ORIGIN_TOLERANCE_MM

    # The shape frame is the catalog object frame, moved by the transform applied.
    R_fit = np.asarray(fit.T_object_shape.rotation().as_matrix())
    R_true = np.asarray(T_map_object.rotation().as_matrix())
    axis_error = _angle_deg(R_fit[:, 0], R_true[:, 0])
    if kind in SYMMETRIC_ENDS:
        axis_error = min(axis_error, 180.0 - axis_error)
    assert axis_error < AXIS_TOLERANCE_DEG
    if kind == "cuboid":  # y along the shorter side, up to sign
        roll_error = _angle_deg(R_fit[:, 1], R_true[:, 1])
        assert min(roll_error, 180.0 - roll_error) < AXIS_TOLERANCE_DEG
    origin_error = np.asarray(fit.T_object_shape.translation() - T_map_object.translation())
    assert np.linalg.norm(origin_error) < ORIGIN_TOLERANCE_MM


@pytest.mark.parametrize("name, kind, touched_end, seed", CASES, ids=[case[1] for case in CASES])
def test_fit_does_not_assume_an_axis_aligned_object(name, kind, touched_end, seed):
    """Any rotation and a translation of tens of mm (the compiled fits of the test above)."""
    rng = np.random.default_rng(100 + seed)
    points = _corrupt(_surface_points(name, rng, touched_end), rng)
    T_map_object = jaxlie.SE3.from_rotation_and_translation(
        jaxlie.SO3.sample_uniform(jax.random.key(seed)), jnp.asarray(rng.uniform(-50, 50, 3), jnp.float32))
    points = np.asarray(T_map_object @ jnp.asarray(points, jnp.float32))
    padded = np.concatenate([points, np.full((N_PADDING, 3), np.nan, np.float32)])
    fit = fit_shape(padded, np.arange(len(padded)) < N_POINTS, kind)
    assert bool(fit.converged)
    for parameter, error in shape_fit_errors(fit, true_shape_parameters(get_object(name), kind)).items():
        assert error["relative_error"] < RELATIVE_TOLERANCE, (parameter, error)
    axis_error = _angle_deg(np.asarray(fit.T_object_shape.rotation().as_matrix())[:, 0],
                            np.asarray(T_map_object.rotation().as_matrix())[:, 0])
    if kind in SYMMETRIC_ENDS:
        axis_error = min(axis_error, 180.0 - axis_error)
    assert axis_error < AXIS_TOLERANCE_DEG
    origin_error = np.asarray(fit.T_object_shape.translation() - T_map_object.translation())
    assert np.linalg.norm(origin_error) < ORIGIN_TOLERANCE_MM


def _cuboid_two_sides_and_an_end(rng: np.random.Generator) -> np.ndarray:
    """(N_POINTS, 3) points uniform over the catalog cuboid's two y sides and its +x end only (the
    mapping protocol's grasps): its z sides (side_1 apart) carry no point."""
    half = np.asarray(get_object("cuboid").extents) / 2  # 40, 10, 12.5 mm
    end_area, side_area = 4 * half[1] * half[2], 2 * 4 * half[0] * half[2]
    n_end = int(N_POINTS * end_area / (end_area + side_area))
    n_side = N_POINTS - n_end
    sides = np.stack([rng.uniform(-half[0], half[0], n_side), rng.choice([-1.0, 1.0], n_side) * half[1],
                      rng.uniform(-half[2], half[2], n_side)], axis=1)
    end = np.stack([np.full(n_end, half[0]), rng.uniform(-half[1], half[1], n_end),
                    rng.uniform(-half[2], half[2], n_end)], axis=1)
    points = np.concatenate([sides, end])
    assert np.max(np.abs(np.asarray(get_object("cuboid").solid.sdf(jnp.asarray(points, jnp.float32))))) < 1e-3
    return points[rng.permutation(N_POINTS)]


def test_untouched_cuboid_sides_go_where_their_neighbours_stop():
    """No point lies on the z sides, so the least squares cannot place them (any z extent beyond
    the y sides' points costs the same); they go where the y sides' points stop."""
    truth = true_shape_parameters(get_object("cuboid"), "cuboid")
    least_squares_only = []
    for seed in (1, 4, 5):
        rng = np.random.default_rng(seed)
        points = _corrupt(_cuboid_two_sides_and_an_end(rng), rng)
        T_map_object = _random_pose(rng)
        points = np.asarray(T_map_object @ jnp.asarray(points, jnp.float32))
        padded = np.concatenate([points, np.full((N_PADDING, 3), np.nan, np.float32)])
        valid = np.arange(len(padded)) < N_POINTS
        fit = fit_shape(padded, valid, "cuboid")
        assert bool(fit.converged)
        for parameter, error in shape_fit_errors(fit, truth).items():
            assert error["relative_error"] < RELATIVE_TOLERANCE, (seed, parameter, error)
        # The side_1 faces are centred on the object: the shape origin is where it was put.
        origin_error = np.asarray(fit.T_object_shape.translation() - T_map_object.translation())
        assert np.linalg.norm(origin_error) < ORIGIN_TOLERANCE_MM
        # Without an extent cloud (none of it valid) only the least squares places the z sides.
        plain = fit_shape(padded, valid, "cuboid", extent_points=padded, extent_valid=np.zeros_like(valid))
        least_squares_only.append(shape_fit_errors(plain, truth)["side_1_mm"]["relative_error"])
    assert max(least_squares_only) > 4 * RELATIVE_TOLERANCE  # unpinned: wherever the solver stopped


def test_extent_cloud_must_come_whole():
    points = np.zeros((10, 3), np.float32)
    with pytest.raises(ValueError, match="extent_points and extent_valid"):
        fit_shape(points, np.ones(10, bool), "cuboid", extent_points=points)
    with pytest.raises(ValueError, match=r"extent_points \(N, 3\)"):
        fit_shape(points, np.ones(10, bool), "cuboid", extent_points=points[:, :2], extent_valid=np.ones(10, bool))


def test_empty_cloud_gives_finite_unconverged_fit():
    points = np.full((N_POINTS + N_PADDING, 3), np.nan, np.float32)
    fit = fit_shape(points, np.zeros(len(points), bool), "cylinder")  # the compiled cylinder fit
    assert not bool(fit.converged)
    leaves = jax.tree.leaves(fit)
    assert all(np.all(np.isfinite(np.asarray(leaf))) for leaf in leaves)
    assert float(fit.inlier_fraction) == 0.0
    assert float(fit.parameters["radius_mm"]) > 0.0


def test_unknown_kind_is_a_clear_error():
    points = np.zeros((10, 3), np.float32)
    with pytest.raises(ValueError, match="unknown shape kind 'sphere'"):
        fit_shape(points, np.ones(10, bool), "sphere")
    with pytest.raises(ValueError, match="unknown shape kind"):
        true_shape_parameters(get_object("cylinder"), "cone")
    with pytest.raises(ValueError, match="no radius_mm"):
        true_shape_parameters(get_object("cuboid"), "cylinder")
    with pytest.raises(ValueError, match=r"points \(N, 3\)"):
        fit_shape(np.zeros((10, 2), np.float32), np.ones(10, bool), "cuboid")


def test_truth_and_errors_use_table2_names():
    assert SHAPE_KINDS == tuple(TABLE2_PARAMETERS)
    truth = true_shape_parameters(get_object("double_cylinder"), "double_cylinder")
    assert truth == {"big_radius_mm": 16.0, "small_radius_mm": 11.0, "joint_mm": 60.0, "length_mm": 100.0}
    semicone = true_shape_parameters(get_object("semicone"), "semicone")
    assert semicone["slope_rad"] == pytest.approx(math.radians(7.5))
    pyramid = true_shape_parameters(get_object("semipyramid"), "semipyramid")
    assert pyramid == pytest.approx({"base_side_mm": 20.0, "slope_rad": math.radians(7.5), "length_mm": 40.0})
    assert true_shape_parameters(get_object("cuboid"), "cuboid") == {
        "side_1_mm": 25.0, "side_2_mm": 20.0, "length_mm": 80.0}

    fit = ShapeFit(kind="double-cylinder",
                   parameters={"big_radius_mm": jnp.float32(15.2), "small_radius_mm": jnp.float32(11.0),
                               "joint_mm": jnp.float32(63.0), "length_mm": jnp.float32(90.0)},
                   T_object_shape=jaxlie.SE3.identity(), rms_residual_mm=jnp.float32(0.1),
                   inlier_fraction=jnp.float32(1.0), converged=jnp.bool_(True), iterations=jnp.int32(3))
    errors = shape_fit_errors(fit, truth)
    assert set(errors) == {"big_radius_mm", "small_radius_mm", "joint_mm"}  # no nuisance length
    assert errors["big_radius_mm"]["relative_error"] == pytest.approx(0.8 / 16.0, rel=1e-5)
    assert errors["joint_mm"] == pytest.approx({"estimate": 63.0, "true": 60.0, "relative_error": 0.05})


# ---------------------------------------------------------------- the least-squares solver

_T = np.linspace(0.0, 4.0, 40)
_THETA_TRUE = np.array([2.0, 1.3, 0.5])
_THETA0 = np.array([1.0, 0.5, 0.0], np.float32)


def _decay_data(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a, b, c = _THETA_TRUE
    y = a * np.exp(-b * _T) + c + rng.normal(0.0, 0.02, _T.shape)
    y[rng.choice(len(_T), 4, replace=False)] += rng.choice([-1.0, 1.0], 4) * rng.uniform(0.5, 1.0, 4)
    return y


def _decay_residuals(theta, y):
    t = jnp.asarray(_T, jnp.float32)
    return theta[0] * jnp.exp(-theta[1] * t) + theta[2] - y


@functools.partial(jax.jit, static_argnames=("loss",))
def _solve_decay(y, weights, max_iterations, *, loss):
    """The solver on the decay problem; weights and max_iterations are traced (no recompiles)."""
    return solve_least_squares(lambda theta: _decay_residuals(theta, y), jnp.asarray(_THETA0),
                               max_iterations=max_iterations, robust_scale_mm=0.1, loss=loss,
                               weights=weights)


@pytest.mark.parametrize("loss", ["linear", "huber", "cauchy"])
def test_solver_matches_scipy_least_squares(loss):
    y = _decay_data(0)

    def residuals(theta):
        return theta[0] * np.exp(-theta[1] * _T) + theta[2] - y

    reference = scipy.optimize.least_squares(residuals, _THETA0.astype(np.float64), loss=loss, f_scale=0.1,
                                             method="trf", xtol=1e-14, ftol=1e-14, gtol=1e-14)
    result = _solve_decay(jnp.asarray(y, jnp.float32), jnp.ones(len(_T), jnp.float32), 100, loss=loss)
    assert bool(result.converged)
    np.testing.assert_allclose(np.asarray(result.theta), reference.x, rtol=2e-3, atol=2e-3)
    # scipy's cost is the same robust cost: 0.5 sum r^2, or sum f_scale^2 rho((r / f_scale)^2) / 2.
    np.testing.assert_allclose(float(result.cost), reference.cost, rtol=1e-3)
    np.testing.assert_allclose(np.asarray(result.residuals), residuals(np.asarray(result.theta, np.float64)),
                               atol=1e-4)


def test_solver_robust_losses_resist_outliers():
    y = jnp.asarray(_decay_data(1), jnp.float32)
    ones = jnp.ones(len(_T), jnp.float32)
    plain = np.asarray(_solve_decay(y, ones, 100, loss="linear").theta)
    robust = np.asarray(_solve_decay(y, ones, 100, loss="cauchy").theta)
    assert np.max(np.abs(robust - _THETA_TRUE)) < 0.5 * np.max(np.abs(plain - _THETA_TRUE))


def test_solver_vmaps_like_a_loop():
    ys = jnp.asarray(np.stack([_decay_data(seed) for seed in range(3)]), jnp.float32)
    ones = jnp.ones(len(_T), jnp.float32)
    batched = jax.vmap(lambda y: _solve_decay(y, ones, 100, loss="huber"))(ys)
    for i in range(3):
        single = _solve_decay(ys[i], ones, 100, loss="huber")
        np.testing.assert_allclose(np.asarray(batched.theta[i]), np.asarray(single.theta), rtol=1e-4, atol=1e-5)
        assert bool(batched.converged[i]) == bool(single.converged)


def test_a_residual_without_a_finite_derivative_does_not_stop_the_solver():
    """One residual whose derivative is NaN at every theta (a kink met exactly, as a point on a
    distance function's ridge): it counts in the cost but gives no direction; the fit of the
    others is scipy's on them alone (the solver used to stop at once, reporting convergence)."""
    y = _decay_data(0)
    kinked = lambda theta: jnp.concatenate([_decay_residuals(theta, jnp.asarray(y, jnp.float32)),  # noqa: E731
                                            jnp.sqrt(jnp.zeros(1) * theta[0] ** 2)])  # d/dtheta: NaN
    result = jax.jit(lambda: solve_least_squares(kinked, jnp.asarray(_THETA0), max_iterations=100,
                                                 robust_scale_mm=0.1, loss="linear"))()
    reference = scipy.optimize.least_squares(lambda theta: theta[0] * np.exp(-theta[1] * _T) + theta[2] - y,
                                             _THETA0.astype(np.float64), xtol=1e-14, ftol=1e-14, gtol=1e-14)
    assert bool(result.converged)
    np.testing.assert_allclose(np.asarray(result.theta), reference.x, rtol=2e-3, atol=2e-3)


def test_solver_failures_come_back_as_flags():
    y = _decay_data(0)
    ones = jnp.ones(len(_T), jnp.float32)
    # Masked-out residuals may be NaN; they are ignored.
    y_nan = jnp.asarray(np.where(np.arange(len(_T)) < 5, np.nan, y), jnp.float32)
    weights = jnp.asarray(np.arange(len(_T)) >= 5, jnp.float32)
    masked = _solve_decay(y_nan, weights, 100, loss="cauchy")
    assert bool(masked.converged) and np.all(np.isfinite(np.asarray(masked.theta)))
    # A non-finite cost at the start: not converged, theta0 back.
    broken = _solve_decay(y_nan, ones, 100, loss="cauchy")
    assert not bool(broken.converged)
    np.testing.assert_array_equal(np.asarray(broken.theta), _THETA0)
    # Too few iterations (the first one evaluates theta0): not converged.
    short = _solve_decay(jnp.asarray(y, jnp.float32), ones, 2, loss="cauchy")
    assert not bool(short.converged) and int(short.iterations) == 2
    with pytest.raises(ValueError, match="unknown loss"):
        solve_least_squares(lambda theta: theta, jnp.zeros(2), max_iterations=1, robust_scale_mm=1.0, loss="l1")
