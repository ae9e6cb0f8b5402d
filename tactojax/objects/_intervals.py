"""Exact ray / solid intervals: the building blocks of analytic ray casting (pure JAX).

A ray ``o + t d`` (t >= 0) meets a convex solid in one interval ``[enter, exit]``. Intervals are
pairs of arrays broadcasting over the rays' batch shape; an empty interval has
``enter > exit`` (we use ``(inf, -inf)``). Every function here is closed form, so ray casting
is exact (no marching) and differentiable in the rays and the solids' parameters.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

Interval = tuple[Float[Array, "*rays"], Float[Array, "*rays"]]
_EPS = 1e-9


def empty_like(x: Float[Array, "*rays"]) -> Interval:
    return jnp.full_like(x, jnp.inf), jnp.full_like(x, -jnp.inf)


def is_empty(interval: Interval) -> Float[Array, "*rays"]:
    return interval[0] > interval[1]


def intersect(*intervals: Interval) -> Interval:
    """Intersection of intervals (each may be empty)."""
    enter = intervals[0][0]
    exit_ = intervals[0][1]
    for lo, hi in intervals[1:]:
        enter = jnp.maximum(enter, lo)
        exit_ = jnp.minimum(exit_, hi)
    return enter, exit_


def ahead(interval: Interval) -> Interval:
    """The part of an interval at t >= 0 (enter == 0 exactly when the origin is inside)."""
    lo, hi = interval
    keep = (hi >= 0.0) & (lo <= hi)
    return jnp.where(keep, jnp.maximum(lo, 0.0), jnp.inf), jnp.where(keep, hi, -jnp.inf)


def half_space(
    normal: Float[Array, "3"], offset: Float[Array, ""], origins, directions
) -> Interval:
    """Where the ray satisfies ``normal . p <= offset``."""
    slope = directions @ normal
    room = offset - origins @ normal
    safe = jnp.where(jnp.abs(slope) > _EPS, slope, 1.0)
    bound = room / safe
    inf = jnp.full_like(bound, jnp.inf)
    lo = jnp.where(slope < -_EPS, bound, -inf)
    hi = jnp.where(slope > _EPS, bound, inf)
    parallel_outside = (jnp.abs(slope) <= _EPS) & (room < 0.0)
    return jnp.where(parallel_outside, inf, lo), jnp.where(parallel_outside, -inf, hi)


def slab(axis: int, half_width: Float[Array, ""], origins, directions) -> Interval:
    """Where ``|p[axis]| <= half_width``."""
    normal = jnp.zeros(3).at[axis].set(1.0)
    return intersect(
        half_space(normal, half_width, origins, directions),
        half_space(-normal, half_width, origins, directions),
    )


def quadratic(a, b, c) -> tuple[Interval, Interval]:
    """Where ``a t^2 + b t + c <= 0``, as up to two intervals (the second for a < 0).

    a > 0: one interval between the roots; a < 0: (-inf, t1] and [t2, inf); a ~ 0: the linear
    inequality. Empty intervals where nothing satisfies it.
    """
    discriminant = b * b - 4.0 * a * c
    root = jnp.sqrt(jnp.maximum(discriminant, 1e-20))
    safe_a = jnp.where(jnp.abs(a) > _EPS, a, 1.0)
    t_minus = (-b - root) / (2.0 * safe_a)
    t_plus = (-b + root) / (2.0 * safe_a)
    small, large = jnp.minimum(t_minus, t_plus), jnp.maximum(t_minus, t_plus)
    inf = jnp.full_like(a, jnp.inf)
    # Linear case: b t + c <= 0.
    safe_b = jnp.where(jnp.abs(b) > _EPS, b, 1.0)
    linear_bound = -c / safe_b
    linear_lo = jnp.where(b < -_EPS, linear_bound, jnp.where((jnp.abs(b) <= _EPS) & (c > 0), inf, -inf))
    linear_hi = jnp.where(b > _EPS, linear_bound, jnp.where((jnp.abs(b) <= _EPS) & (c > 0), -inf, inf))

    is_linear = jnp.abs(a) <= _EPS
    has_roots = discriminant >= 0.0
    # First interval: [small, large] for a > 0; (-inf, small] for a < 0 (all t if no roots).
    first_lo = jnp.where(a > 0, jnp.where(has_roots, small, inf), -inf)
    first_hi = jnp.where(a > 0, jnp.where(has_roots, large, -inf), jnp.where(has_roots, small, inf))
    second_lo = jnp.where((a < 0) & has_roots, large, inf)
    second_hi = jnp.where((a < 0) & has_roots, inf, -inf)
    first = (jnp.where(is_linear, linear_lo, first_lo), jnp.where(is_linear, linear_hi, first_hi))
    second = (jnp.where(is_linear, inf, second_lo), jnp.where(is_linear, -inf, second_hi))
    return first, second


def union_first(*intervals: Interval) -> Interval:
    """First interval (smallest enter) of a union; its exit is that piece's exit."""
    enter, exit_ = intervals[0]
    for lo, hi in intervals[1:]:
        take = lo < enter
        enter = jnp.where(take, lo, enter)
        exit_ = jnp.where(take, hi, exit_)
    return enter, exit_


def pick_nonempty(first: Interval, second: Interval) -> Interval:
    """``first`` if it is non-empty, else ``second`` (for convex results of two candidate pieces)."""
    use_first = ~is_empty(first)
    return jnp.where(use_first, first[0], second[0]), jnp.where(use_first, first[1], second[1])


def difference_first(solid: Interval, cut: Interval) -> Interval:
    """First interval of ``solid`` minus ``cut`` (both single intervals at t >= 0)."""
    (a0, a1), (b0, b1) = solid, cut
    cut_covers_entry = ~is_empty(cut) & (b0 <= a0) & (a0 <= b1)
    enter = jnp.where(cut_covers_entry, b1, a0)
    exit_ = jnp.where(cut_covers_entry, a1, jnp.where(~is_empty(cut) & (b0 > a0), jnp.minimum(a1, b0), a1))
    nonempty = ~is_empty(solid) & (enter < exit_)
    return jnp.where(nonempty, enter, jnp.inf), jnp.where(nonempty, exit_, -jnp.inf)
