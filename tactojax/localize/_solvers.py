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


def _cholesky(matrix: Float[Array, "n n"]) -> list[list]:
    """Lower Cholesky factor as nested lists of scalars (unrolled: n is small and static)."""
    n = matrix.shape[-1]
    lower = [[None] * n for _ in range(n)]
    for j in range(n):
        diagonal = matrix[j, j] - sum((lower[j][k] ** 2 for k in range(j)), 0.0)
        lower[j][j] = jnp.sqrt(jnp.maximum(diagonal, jnp.finfo(matrix.dtype).tiny))
        for i in range(j + 1, n):
            lower[i][j] = (matrix[i, j] - sum((lower[i][k] * lower[j][k] for k in range(j)), 0.0)) / lower[j][j]
    return lower


def _substitute(lower: list[list], vector: Float[Array, "n"]) -> Float[Array, "n"]:
    """``(L L^T)^-1 vector`` by forward then backward substitution."""
    n = len(lower)
    forward = []
    for i in range(n):
        forward.append((vector[i] - sum((lower[i][k] * forward[k] for k in range(i)), 0.0)) / lower[i][i])
    solution = [None] * n
    for i in reversed(range(n)):
        solution[i] = (forward[i] - sum((lower[k][i] * solution[k] for k in range(i + 1, n)), 0.0)) / lower[i][i]
    return jnp.stack(solution)


@jax.custom_jvp
def solve_positive_definite(matrix: Float[Array, "n n"], vector: Float[Array, "n"]) -> Float[Array, "n"]:
    """``matrix^-1 vector`` for a small symmetric positive definite matrix (unrolled Cholesky).

    For the 6 x 6 normal equations this fuses into a few element-wise kernels: cheaper to run
    and to compile than a LAPACK call on CPU. Its derivative reuses the factor (d x =
    A^-1 (d b - d A x)), so differentiating ICP never differentiates the factorisation.
    """
    return _substitute(_cholesky(matrix), vector)


@solve_positive_definite.defjvp
def _solve_positive_definite_jvp(primals, tangents):
    matrix, vector = primals
    d_matrix, d_vector = tangents
    lower = _cholesky(matrix)
    solution = _substitute(lower, vector)
    return solution, _substitute(lower, d_vector - d_matrix @ solution)


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
