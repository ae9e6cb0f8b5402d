"""Poisson integration against a sparse least-squares reference (scipy)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg
from jax.test_util import check_grads

from tactojax.geometry import heightmap_gradient
from tactojax.shape import integrate_gradient, zero_background


def _reference(slope: np.ndarray, mm_per_px: float) -> np.ndarray:
    """argmin |Dx h - sx|^2 + |Dy h - sy|^2 with forward differences, zero mean (scipy lsqr)."""
    height, width = slope.shape[:2]

    def difference(n):
        return scipy.sparse.diags([-np.ones(n - 1), np.ones(n - 1)], [0, 1], shape=(n - 1, n))

    dx = scipy.sparse.kron(scipy.sparse.eye(height), difference(width))
    dy = scipy.sparse.kron(difference(height), scipy.sparse.eye(width))
    step_x = 0.5 * (slope[:, 1:, 0] + slope[:, :-1, 0]) * mm_per_px
    step_y = 0.5 * (slope[1:, :, 1] + slope[:-1, :, 1]) * mm_per_px
    system = scipy.sparse.vstack([dx, dy, np.ones((1, height * width))]).tocsr()
    rhs = np.concatenate([step_x.ravel(), step_y.ravel(), [0.0]])
    solution = scipy.sparse.linalg.lsqr(system, rhs, atol=1e-14, btol=1e-14, iter_lim=20000)[0]
    return solution.reshape(height, width)


# One compilation per shape for all tests (eager calls would compile every primitive).
_integrate = jax.jit(integrate_gradient, static_argnums=1)
_integrate_anchored = jax.jit(lambda slope, mm_per_px: zero_background(integrate_gradient(slope, mm_per_px)),
                              static_argnums=1)


@pytest.mark.parametrize("seed", [0, 1])
def test_matches_sparse_least_squares(seed):
    slope = np.random.default_rng(seed).normal(size=(7, 9, 2)).astype(np.float32)
    expected = _reference(slope.astype(np.float64), 0.3)
    np.testing.assert_allclose(_integrate(jnp.asarray(slope), 0.3), expected, atol=2e-4)


def test_recovers_smooth_surface_and_vmaps():
    rows, cols = np.mgrid[:40, :50] * 0.2
    bumps = np.stack([np.exp(-((cols - 5 - k) ** 2 + (rows - 4) ** 2) / 4.0) for k in range(3)])
    slopes = jax.vmap(lambda h: heightmap_gradient(h, 0.2))(jnp.asarray(bumps, jnp.float32))
    batched = jax.jit(jax.vmap(lambda s: zero_background(integrate_gradient(s, 0.2))))(slopes)
    for k in range(3):
        single = _integrate_anchored(slopes[k], 0.2)
        np.testing.assert_allclose(batched[k], single, atol=1e-5)
        assert np.abs(np.asarray(single) - bumps[k]).max() < 0.02  # peak height 1 mm


def test_zero_background_anchors_the_undeformed_gel():
    heightmap = jnp.zeros((20, 20)).at[5:9, 5:9].set(1.0) + 3.0
    anchored = zero_background(heightmap, quantile=0.1)
    assert float(anchored.min()) == 0.0 and float(anchored.max()) == 1.0


def test_gradients():
    slope = jnp.asarray(np.random.default_rng(3).normal(size=(5, 6, 2)), jnp.float32)
    check_grads(jax.jit(lambda s: integrate_gradient(s, 0.5)), (slope,), order=1, modes=["rev"],
                atol=1e-2, rtol=1e-2)


def test_large_images_use_the_ffts_with_the_same_solution():
    # A side above MATRIX_DCT_MAX_PX takes the FFT path; both paths solve the same least squares.
    from tactojax.shape._poisson import MATRIX_DCT_MAX_PX

    slope = np.random.default_rng(5).normal(size=(3, MATRIX_DCT_MAX_PX + 9, 2)).astype(np.float32)
    expected = _reference(slope.astype(np.float64), 0.3)
    np.testing.assert_allclose(_integrate(jnp.asarray(slope), 0.3), expected, atol=5e-4)
