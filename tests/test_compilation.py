"""``kernel_count``: the kernels of a compiled program, counted from its optimized HLO; and
``CompilationCounter``, which the live loop's tests use to prove that nothing recompiles."""

import jax
import jax.numpy as jnp

from tactojax import CompilationCounter, kernel_count


def test_elementwise_work_fuses_into_one_kernel_and_library_calls_count_apart():
    x = jnp.ones((8, 8))
    fused = jax.jit(lambda x: jnp.sin(x) * 2.0 + x).lower(x).compile()
    assert kernel_count(fused) == 1
    # An elementwise fusion, a sort and a dot cannot fuse into one another.
    three = jax.jit(lambda x: jnp.sort(jnp.sin(x) + 1.0) @ x).lower(x).compile()
    assert kernel_count(three) == 3


def test_programs_with_several_outputs_count_their_kernels():
    x = jnp.ones((8, 8))
    # Two outputs (a tuple-shaped root, which launches nothing): one fusion and one sort.
    two = jax.jit(lambda x: (jnp.sin(x) * 2.0, jnp.sort(x.ravel()))).lower(x).compile()
    assert kernel_count(two) == 2


def test_compilation_counter_counts_compilations_not_cache_hits():
    def triple_plus_one(x):
        return 3.0 * x + 1.0

    f = jax.jit(triple_plus_one)
    three, other_three, four = jnp.ones(3), jnp.zeros(3), jnp.ones(4)  # made outside: they compile too
    logging_before = jax.config.jax_log_compiles
    with CompilationCounter() as compiles:
        f(three)
        f(other_three)  # the same shapes: a cache hit
    assert compiles.count == 1 and "triple_plus_one" in compiles.messages[0]
    with CompilationCounter() as compiles:
        f(four)  # a new shape compiles
        f(three)
    assert compiles.count == 1
    with CompilationCounter() as compiles:
        f(four)
    assert compiles.messages == []
    assert jax.config.jax_log_compiles == logging_before  # restored on exit
