"""``kernel_count``: the kernels of a compiled program, counted from its optimized HLO."""

import jax
import jax.numpy as jnp

from tactojax._compilation import kernel_count


def test_elementwise_work_fuses_into_one_kernel_and_library_calls_count_apart():
    x = jnp.ones((8, 8))
    fused = jax.jit(lambda x: jnp.sin(x) * 2.0 + x).lower(x).compile()
    assert kernel_count(fused) == 1
    # An elementwise fusion, a sort and a dot cannot fuse into one another.
    three = jax.jit(lambda x: jnp.sort(jnp.sin(x) + 1.0) @ x).lower(x).compile()
    assert kernel_count(three) == 3



def test_instructions_with_tuple_shapes_are_counted():
    x = jnp.arange(8.0)
    # A variadic reduction returns a tuple: (f32[], s32[]) reduce(...).
    program = jax.jit(lambda x: jnp.argmax(x) + jnp.sum(jnp.cos(x)).astype(jnp.int32)).lower(x).compile()
    assert 1 <= kernel_count(program) <= 3
