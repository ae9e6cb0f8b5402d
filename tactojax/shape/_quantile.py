"""Exact quantiles: the values a sort would put at given ranks, by selection on a CPU.

XLA's CPU sort calls a compiled comparator per comparison; sorting the 19,200 heights of a
120 x 160 heightmap to read one quantile took about 3 ms on 2 busy cores, a third of
``predict`` (issue 17). Selection finds the same values with 32 counting passes in about
0.3 ms (``benchmarks/heightmap_speed.py``).

On a GPU the opposite holds: the 32 passes are a loop of 128 kernel launches, 0.16 ms of GPU
time but about 0.8 ms of launch overhead per heightmap on an H200 machine (issue 27), where one
sort is a handful of kernels, and a few hundred values (ICP's residuals) are ranked fastest by
comparing all pairs in one kernel. :func:`order_statistics` therefore selects on a CPU, and
elsewhere compares all pairs or sorts (``lax.platform_dependent``); all return the same elements.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Float, Int, UInt


COMPARISON_MAX = 256
"""On an accelerator, up to this many values are ranked by comparing all pairs, more by a sort."""


def order_statistics(values: Float[Array, "N"], ranks: tuple[int, ...] | Int[Array, "R"]) -> Float[Array, "R"]:
    """``jnp.sort(values)[ranks]``: by bisection on a CPU (:func:`order_statistics_by_bisection`),
    on an accelerator by comparing all pairs up to ``COMPARISON_MAX`` values
    (:func:`order_statistics_by_comparison`) and by a sort beyond (see the module docstring).

    Args:
        values: (N,) floats, not NaN (infinities order as floats do).
        ranks: R positions in the sorted order, each in [0, N): static, or traced (e.g. a count
            of valid values).

    Returns:
        (R,) the values at those positions.
    """
    return lax.platform_dependent(values, jnp.asarray(ranks, jnp.int32), cpu=order_statistics_by_bisection,
                                  default=_on_an_accelerator)


def _on_an_accelerator(values: Float[Array, "N"], ranks: Int[Array, "R"]) -> Float[Array, "R"]:
    if values.shape[0] <= COMPARISON_MAX:
        return order_statistics_by_comparison(values, ranks)
    return order_statistics_by_sort(values, ranks)


def order_statistics_by_comparison(values: Float[Array, "N"],
                                   ranks: tuple[int, ...] | Int[Array, "R"]) -> Float[Array, "R"]:
    """``jnp.sort(values)[ranks]`` without a sort: for each rank ``r``, the largest value with at
    most ``r`` values below it, from all N^2 comparisons in one fused reduction (what
    :func:`order_statistics` runs on an accelerator for a few hundred values)."""
    below = jnp.sum(values[None, :] < values[:, None], axis=1)  # (N,)
    ranks = jnp.asarray(ranks, jnp.int32)
    return jnp.max(jnp.where(below[None, :] <= ranks[:, None], values[None, :], -jnp.inf), axis=1)


def order_statistics_by_sort(values: Float[Array, "N"], ranks: tuple[int, ...] | Int[Array, "R"]) -> Float[Array, "R"]:
    """``jnp.sort(values)[ranks]`` (what :func:`order_statistics` runs on an accelerator for more
    than ``COMPARISON_MAX`` values)."""
    return jnp.sort(values)[jnp.asarray(ranks, jnp.int32)]


def order_statistics_by_bisection(values: Float[Array, "N"], ranks: tuple[int, ...] | Int[Array, "R"]) -> Float[Array, "R"]:
    """``jnp.sort(values)[ranks]``, found by bisection instead of a sort (what
    :func:`order_statistics` runs on a CPU).

    Every float maps to an unsigned integer key of its width with the same order
    (:func:`_sortable_keys`). The key of rank ``r`` is the smallest key ``t`` with more than
    ``r`` keys ``<= t``: halving the key range 32 times (64 for float64), each step counting
    the keys at or below its midpoint, finds it. The result is an element of ``values``
    itself (gathered at the first index holding that key), so it is exact, and its gradient
    reaches that element, as through a sort.

    Args:
        values: (N,) floats, not NaN.
        ranks: R positions in the sorted order, each in [0, N) (static or traced).

    Returns:
        (R,) the values at those positions.
    """
    keys = _sortable_keys(lax.stop_gradient(values))
    key_bits = 8 * keys.dtype.itemsize
    ranks = jnp.asarray(ranks, jnp.int32)

    def halve(_, bounds):
        low, high = bounds  # the key of each rank lies in [low, high]
        middle = low + (high - low) // 2
        enough = jnp.sum(keys[:, None] <= middle, axis=0, dtype=jnp.int32) > ranks
        return jnp.where(enough, low, middle + 1), jnp.where(enough, middle, high)

    start = (jnp.zeros(ranks.shape, keys.dtype), jnp.full(ranks.shape, np.iinfo(keys.dtype).max, keys.dtype))
    key, _ = lax.fori_loop(0, key_bits, halve, start)
    return values[jnp.argmax(keys[:, None] == key, axis=0)]


def quantile(values: Float[Array, "N"], q: float) -> Float[Array, ""]:
    """``jnp.quantile(values, q)`` (linear interpolation between the two nearest ranks), exactly.

    Args:
        values: (N,) finite floats.
        q: static quantile in [0, 1].

    Returns:
        () the quantile, with the interpolation weights ``jnp.quantile`` computes (in the
        values' precision).
    """
    real = np.dtype(values.dtype).type
    position = real(q) * real(values.shape[0] - 1)
    low, high = int(np.floor(position)), int(np.ceil(position))
    high_weight = position - real(low)
    low_weight = real(1.0) - high_weight
    low_value, high_value = order_statistics(values, (low, high))
    return low_value * low_weight + high_value * high_weight


def _sortable_keys(values: Float[Array, "N"]) -> UInt[Array, "N"]:
    """Unsigned keys (as wide as the floats) in the order of the values: the sign bit set on
    non-negative values, every bit flipped on negative ones (more negative, smaller key)."""
    unsigned = {2: np.uint16, 4: np.uint32, 8: np.uint64}[values.dtype.itemsize]
    bits = lax.bitcast_convert_type(values, unsigned)
    sign = unsigned(1) << unsigned(8 * values.dtype.itemsize - 1)
    return jnp.where((bits & sign) != 0, ~bits, bits | sign)
