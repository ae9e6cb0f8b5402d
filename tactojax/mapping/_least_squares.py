"""Robust nonlinear least squares: damped Gauss-Newton (Levenberg-Marquardt) with IRLS weights.

Internal solver behind one small interface, so that it can be swapped (for example for jaxopt's
``LevenbergMarquardt``) without touching its callers (shape fits, later ICP):

    result = solve_least_squares(residual_fn, theta0, max_iterations=50, robust_scale_mm=0.5)

It minimises ``sum_i weights_i * rho(r_i(theta))`` where ``r = residual_fn(theta)`` is an (N,)
vector of residuals in mm and ``rho`` is a robust loss of scale ``robust_scale_mm``:

* ``"linear"``: ``rho(r) = r^2 / 2`` (ordinary least squares; the scale is ignored),
* ``"huber"``: ``r^2 / 2`` for ``|r| <= c``, ``c (|r| - c / 2)`` beyond,
* ``"cauchy"``: ``c^2 / 2 log(1 + (r / c)^2)``.

Each iteration evaluates the residuals and their Jacobian (``jax.jacfwd``: theta is small, N
may be ~50k) at a trial point, the first being ``theta0``; the trial is accepted if it lowers
the robust cost, and the damping then shrinks (else it grows). The next trial solves the
Marquardt-damped normal equations at the best point,
``(J^T W J + lambda D) delta = -J^T W r``, with the iteratively-reweighted-least-squares
weights ``W = diag(weights * rho'(r) / r)`` recomputed at its residuals and ``D`` the (floored)
diagonal of ``J^T W J``. The right-hand side is the exact gradient of the robust cost, so the
fixed points are its stationary points (the same ones as ``scipy.optimize.least_squares`` with
the same loss). The residual function is traced once, inside ``jax.jacfwd``.

Everything runs in one ``jax.lax.while_loop`` with a fixed iteration cap, so it jits, vmaps and
never raises: a non-finite cost or an exhausted iteration budget comes back as
``converged=False`` with the last finite parameters.
"""

from __future__ import annotations

import functools

from collections.abc import Callable
from typing import Any, Literal

import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Bool, Float, Int

from tactojax import _struct as struct

Loss = Literal["linear", "huber", "cauchy"]
LOSSES: tuple[str, ...] = ("linear", "huber", "cauchy")

_MIN_DAMPING = 1e-10
_MAX_DAMPING = 1e12


@struct.dataclass
class LeastSquaresResult:
    """Outcome of :func:`solve_least_squares` (a pytree; every field is an array)."""

    theta: Any
    """The parameters at the lowest cost found, same pytree structure as ``theta0``."""
    cost: Float[Array, ""]
    """Robust cost ``sum_i weights_i rho(r_i)`` at ``theta``, mm^2 when residuals are in mm."""
    iterations: Int[Array, ""]
    """Iterations run: evaluations of residuals and Jacobian, the first at ``theta0``."""
    converged: Bool[Array, ""]
    """A tolerance was met (cost, step or gradient) with a finite cost; False when the iteration
    cap was reached first or the cost was not finite."""
    residuals: Float[Array, "N"]
    """Residuals at ``theta`` (0 where the weight is 0), mm."""


def robust_weights(
    residuals: Float[Array, "N"], scale: Float[Array, ""] | float, loss: Loss
) -> Float[Array, "N"]:
    """IRLS weights ``rho'(r) / r`` of a loss (1 for ``"linear"``), in (0, 1]."""
    if loss == "linear":
        return jnp.ones_like(residuals)
    magnitude = jnp.abs(residuals)
    if loss == "huber":
        return jnp.minimum(1.0, scale / jnp.maximum(magnitude, 1e-30))
    if loss == "cauchy":
        return 1.0 / (1.0 + (residuals / scale) ** 2)
    raise ValueError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")


def robust_loss(
    residuals: Float[Array, "N"], scale: Float[Array, ""] | float, loss: Loss
) -> Float[Array, "N"]:
    """Per-residual robust loss ``rho(r)`` (``r^2 / 2`` for ``"linear"``), mm^2."""
    if loss == "linear":
        return 0.5 * residuals**2
    magnitude = jnp.abs(residuals)
    if loss == "huber":
        return jnp.where(magnitude <= scale, 0.5 * residuals**2, scale * (magnitude - 0.5 * scale))
    if loss == "cauchy":
        return 0.5 * scale**2 * jnp.log1p((residuals / scale) ** 2)
    raise ValueError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")


@struct.dataclass
class _State:
    theta: Float[Array, "P"]  # best parameters so far
    residuals: Float[Array, "N"]  # at theta (0 where masked out)
    jacobian: Float[Array, "N P"]  # at theta (0 where masked out)
    cost: Float[Array, ""]  # at theta; inf before the first evaluation
    trial: Float[Array, "P"]  # parameters to evaluate next
    damping: Float[Array, ""]
    iteration: Int[Array, ""]
    done: Bool[Array, ""]
    converged: Bool[Array, ""]


def _marquardt_step(jacobian: Float[Array, "N P"], residuals: Float[Array, "N"], weights: Float[Array, "N"],
                    damping: Float[Array, ""]) -> tuple[Float[Array, "P"], Float[Array, "P"]]:
    """One Levenberg-Marquardt step of weighted least squares (IRLS weights, the damping
    relative to the normal matrix's diagonal, floored so that a parameter the residuals do not
    see gets a finite step): ``(delta, gradient)``, the step (zero where the solve is not
    finite) and the weighted gradient ``J^T W r``."""
    hessian = jacobian.T @ (weights[:, None] * jacobian)
    gradient = jacobian.T @ (weights * residuals)
    diagonal = jnp.diagonal(hessian)
    diagonal = jnp.maximum(diagonal, 1e-9 * jnp.max(diagonal) + 1e-20)
    delta = jnp.linalg.solve(hessian + damping * jnp.diag(diagonal), -gradient)
    return jnp.where(jnp.all(jnp.isfinite(delta)), delta, 0.0), gradient


def solve_least_squares(
    residual_fn: Callable[[Any], Float[Array, "N"]],
    theta0: Any,
    *,
    max_iterations: int | Int[Array, ""],
    robust_scale_mm: Float[Array, ""] | float,
    loss: Loss = "huber",
    weights: Float[Array, "N"] | None = None,
    initial_damping: float = 1e-3,
    cost_tolerance: float = 1e-6,
    step_tolerance: float = 1e-6,
    gradient_tolerance: float = 1e-12,
) -> LeastSquaresResult:
    """Minimise a robust sum of squared residuals by Levenberg-Marquardt (pure JAX, jittable).

    Args:
        residual_fn: ``theta -> (N,)`` residuals, mm; differentiable in theta.
        theta0: initial parameters, any pytree of float arrays (flattened internally).
        max_iterations: cap on iterations, each one evaluation of the residuals and their
            Jacobian (the first at ``theta0``); a Python int or a traced integer.
        robust_scale_mm: scale ``c`` of the robust loss, mm (ignored for ``"linear"``).
        loss: ``"linear"``, ``"huber"`` or ``"cauchy"``; static.
        weights: optional (N,) non-negative per-residual weights (0 masks a residual out, e.g.
            padding); residuals and Jacobian rows with weight 0 are ignored even if not finite.
        initial_damping: initial Marquardt damping ``lambda`` (relative to the diagonal).
        cost_tolerance: stop when an accepted step lowers the cost by less than this fraction.
        step_tolerance: stop when a step is shorter than ``step_tolerance * (|theta| + step_tolerance)``.
        gradient_tolerance: stop when the largest gradient entry times (|theta| + 1) is below
            this fraction of the cost (a stationary point).

    Returns:
        :class:`LeastSquaresResult` with ``theta`` in the structure of ``theta0``.
    """
    if loss not in LOSSES:
        raise ValueError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")
    flat0, unravel = ravel_pytree(theta0)
    flat0 = jnp.asarray(flat0)
    dtype = flat0.dtype
    scale = jnp.asarray(robust_scale_mm, dtype)

    def flat_residuals(flat: Float[Array, "P"]):
        r = jnp.asarray(residual_fn(unravel(flat)), dtype)
        return r, r

    n_residuals = jax.eval_shape(flat_residuals, flat0)[0].shape[0]
    mask_weights = (jnp.ones((n_residuals,), dtype) if weights is None
                    else jnp.asarray(weights, dtype))
    used = mask_weights > 0

    def evaluate(flat: Float[Array, "P"]):
        jacobian, residuals = jax.jacfwd(flat_residuals, has_aux=True)(flat)
        residuals = jnp.where(used, residuals, 0.0)
        cost = jnp.sum(mask_weights * robust_loss(residuals, scale, loss))
        # A residual whose derivative is not finite (a kink of a distance function, met exactly)
        # gives no direction: its row is left out of the step, not allowed to poison it.
        differentiable = used & jnp.all(jnp.isfinite(jacobian), axis=1)
        return residuals, jnp.where(differentiable[:, None], jacobian, 0.0), jnp.where(jnp.isfinite(cost), cost, jnp.inf)

    state = _State(
        theta=flat0,
        residuals=jnp.zeros((n_residuals,), dtype),
        jacobian=jnp.zeros((n_residuals, flat0.shape[0]), dtype),
        cost=jnp.asarray(jnp.inf, dtype),
        trial=flat0,
        damping=jnp.asarray(initial_damping, dtype),
        iteration=jnp.asarray(0, jnp.int32),
        done=jnp.asarray(False),
        converged=jnp.asarray(False),
    )

    def keep_going(state: _State) -> Bool[Array, ""]:
        return ~state.done & (state.iteration < max_iterations)

    step = functools.partial(_iteration, evaluate=evaluate, mask_weights=mask_weights, scale=scale, loss=loss,
                             tolerances=(cost_tolerance, step_tolerance, gradient_tolerance))
    state = jax.lax.while_loop(keep_going, step, state)
    return LeastSquaresResult(
        theta=unravel(state.theta),
        cost=state.cost,
        iterations=state.iteration,
        converged=state.converged & jnp.isfinite(state.cost),
        residuals=state.residuals,
    )


def _iteration(state: _State, *, evaluate: Callable, mask_weights: Float[Array, "N"], scale: Float[Array, ""],
               loss: Loss, tolerances: tuple[float, float, float]) -> _State:
    """One Levenberg-Marquardt iteration: evaluate the trial point (residuals and Jacobian), keep
    it if it lowers the cost (damping / 3) or keep the best point (damping x 4), test convergence
    (``tolerances``: cost, step, gradient; see :func:`solve_least_squares`), and propose the next
    trial from the best point."""
    cost_tolerance, step_tolerance, gradient_tolerance = tolerances
    # Evaluate the trial point (the Jacobian with it: the residuals are traced only here).
    residuals, jacobian, cost = evaluate(state.trial)
    first = state.iteration == 0
    accept = cost < state.cost  # the first evaluation is accepted whenever it is finite
    step_length = jnp.linalg.norm(state.trial - state.theta)
    small_step = ~first & (step_length <= step_tolerance * (jnp.linalg.norm(state.theta) + step_tolerance))
    small_decrease = ~first & accept & (state.cost - cost <= cost_tolerance * state.cost)
    theta = jnp.where(accept, state.trial, state.theta)
    residuals = jnp.where(accept, residuals, state.residuals)
    jacobian = jnp.where(accept, jacobian, state.jacobian)
    cost = jnp.where(accept, cost, state.cost)
    damping = jnp.where(first, state.damping,
                        jnp.where(accept, state.damping / 3.0, state.damping * 4.0))
    damping = jnp.clip(damping, _MIN_DAMPING, _MAX_DAMPING)

    # Next trial from the best point.
    delta, gradient = _marquardt_step(jacobian, residuals, mask_weights * robust_weights(residuals, scale, loss),
                                      damping)
    stationary = (jnp.max(jnp.abs(gradient) * (jnp.abs(theta) + 1.0))
                  <= gradient_tolerance * jnp.maximum(cost, 1e-30))

    failed = ~jnp.isfinite(cost)  # not even theta0 gave a finite cost
    converged = ~failed & (stationary | small_step | small_decrease)
    stuck = ~accept & (state.damping >= _MAX_DAMPING)
    return _State(
        theta=theta,
        residuals=residuals,
        jacobian=jacobian,
        cost=cost,
        trial=theta + delta,
        damping=damping,
        iteration=state.iteration + 1,
        done=failed | converged | stuck,
        converged=converged,
    )
