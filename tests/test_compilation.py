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



def test_programs_with_several_outputs_count_their_kernels():
    x = jnp.ones((8, 8))
    # Two outputs (a tuple-shaped root, which launches nothing): one fusion and one sort.
    two = jax.jit(lambda x: (jnp.sin(x) * 2.0, jnp.sort(x.ravel()))).lower(x).compile()
    assert kernel_count(two) == 2
