"""Pose updates for ICP behind one small interface: Gauss-Newton, or jaxopt Levenberg-Marquardt.

A solver takes the weighted residuals of the current correspondences as a function of a
tangent step ``delta`` (se(3), translation then rotation, as ``jaxlie.SE3.exp``) and returns
the step. jaxopt is no longer developed upstream: it is imported only here, so that replacing
it (e.g. with optimistix) touches this one module.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

SOLVERS = ("gauss-newton", "levenberg-marquardt")
"""Names accepted by :func:`pose_step`."""

ResidualFunction = Callable[[Float[Array, "6"]], Float[Array, "P"]]


def _eliminate(matrix: Float[Array, "n n"], vectors: Float[Array, "n m"]) -> Float[Array, "n m"]:
    """``matrix^-1 vectors`` by Gauss-Jordan elimination without pivoting (``matrix``
    symmetric positive definite), unrolled: n is small and static.

    Each step updates the whole augmented matrix at once, so the 6 x 6 normal equations take
    six small fused kernels (a scalar Cholesky factorisation and substitution take dozens).
    """
    n = matrix.shape[-1]
    augmented = jnp.concatenate([matrix, vectors], axis=1)
    row = jnp.arange(n)[:, None]
    for k in range(n):
        pivot = augmented[k] / augmented[k, k]
        augmented = jnp.where(row == k, pivot, augmented - augmented[:, k:k + 1] * pivot)
    return augmented[:, n:]


@jax.custom_jvp
def solve_positive_definite(matrix: Float[Array, "n n"], vector: Float[Array, "n"]) -> Float[Array, "n"]:
    """``matrix^-1 vector`` for a small symmetric positive definite matrix (:func:`_eliminate`).

    Cheaper to run and to compile than a LAPACK call on CPU for the 6 x 6 normal equations.
    Its derivative goes through the inverse (d x = A^-1 (d b - d A x)), so differentiating
    ICP never differentiates the elimination.
    """
    return _eliminate(matrix, vector[:, None])[:, 0]


@solve_positive_definite.defjvp
def _solve_positive_definite_jvp(primals, tangents):
    matrix, vector = primals
    d_matrix, d_vector = tangents
    n = matrix.shape[-1]
    inverse_and_solution = _eliminate(matrix, jnp.concatenate([jnp.eye(n, dtype=matrix.dtype), vector[:, None]], 1))
    inverse, solution = inverse_and_solution[:, :n], inverse_and_solution[:, n]
    return solution, inverse @ (d_vector - d_matrix @ solution)


def gauss_newton_step(
    residual_fn: ResidualFunction, *, jacobian: Float[Array, "P 6"] | None = None, damping: float = 1e-6
) -> tuple[Float[Array, "6"], Bool[Array, ""]]:
    """One Gauss-Newton step from ``delta = 0``.

    Solves ``(J^T J + lambda I) delta = -J^T r`` with ``lambda = damping * trace(J^T J) / 6``
    (plus a tiny floor), so that directions the residuals do not constrain (a flat patch
    slides freely in its plane) get no step instead of a huge one.

    Args:
        residual_fn: weighted residuals (P,) as a function of the step (6,).
        jacobian: (P, 6) its Jacobian at 0 when known in closed form (else forward-mode AD).
        damping: relative Levenberg damping.

    Returns:
        the step (6,) and ok (False, with a zero step, if the solve was not finite).
    """
    zero = jnp.zeros(6)
    if jacobian is None:
        residuals, linear = jax.linearize(residual_fn, zero)
        jacobian = jax.vmap(linear, out_axes=1)(jnp.eye(6, dtype=zero.dtype))  # (P, 6)
    else:
        residuals = residual_fn(zero)
    hessian = jacobian.T @ jacobian
    lam = damping * jnp.trace(hessian) / 6.0 + 1e-9
    delta = solve_positive_definite(hessian + lam * jnp.eye(6, dtype=hessian.dtype), -(jacobian.T @ residuals))
    ok = jnp.all(jnp.isfinite(delta))
    return jnp.where(ok, delta, 0.0), ok


def levenberg_marquardt_step(
    residual_fn: ResidualFunction, *, iterations: int = 5, damping: float = 1e-6
) -> tuple[Float[Array, "6"], Bool[Array, ""]]:
    """A few iterations of ``jaxopt.LevenbergMarquardt`` from ``delta = 0``.

    Args:
        residual_fn: weighted residuals (P,) as a function of the step (6,).
        iterations: LM iterations (each re-evaluates ``residual_fn``).
        damping: initial LM damping parameter.

    Returns:
        the step (6,) and ok (False, with a zero step, if it was not finite).
    """
    with warnings.catch_warnings():  # jaxopt warns on import that it is unmaintained (see above)
        warnings.simplefilter("ignore", DeprecationWarning)
        import jaxopt

    solver = jaxopt.LevenbergMarquardt(
        residual_fun=residual_fn, maxiter=iterations, damping_parameter=damping,
        solver="cholesky", materialize_jac=True, implicit_diff=False, jit=True, unroll=True,
        tol=1e-9, xtol=1e-9, gtol=1e-9)
    delta = solver.run(jnp.zeros(6)).params
    ok = jnp.all(jnp.isfinite(delta))
    return jnp.where(ok, delta, 0.0), ok


def pose_step(
    residual_fn: ResidualFunction,
    solver: str = "gauss-newton",
    *,
    jacobian: Float[Array, "P 6"] | None = None,
    lm_iterations: int = 5,
) -> tuple[Float[Array, "6"], Bool[Array, ""]]:
    """The pose update of one ICP iteration with the named solver (see :data:`SOLVERS`).

    Args:
        residual_fn: weighted residuals (P,) as a function of the tangent step (6,).
        solver: ``"gauss-newton"`` (one damped step) or ``"levenberg-marquardt"`` (jaxopt).
        jacobian: (P, 6) Jacobian of ``residual_fn`` at 0, if known (Gauss-Newton uses it).
        lm_iterations: iterations of the Levenberg-Marquardt solver.

    Returns:
        the step (6,) and ok (False, with a zero step, when the solve failed).
    """
    if solver == "gauss-newton":
        return gauss_newton_step(residual_fn, jacobian=jacobian)
    if solver == "levenberg-marquardt":
        return levenberg_marquardt_step(residual_fn, iterations=lm_iterations)
    raise ValueError(f"unknown solver {solver!r}; choose one of {SOLVERS}")
