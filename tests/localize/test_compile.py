"""The localization stage's top-level programs compile without XLA:CPU's YNNPACK library fusions, and
compute what jax.jit's do."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tactojax.localize import _compile
from tactojax.localize._compile import COMPILER_OPTIONS, top_level_jit


def _reduction(x, scale):
    return jnp.sum(jnp.sin(x) ** 2 * scale, axis=0) + jnp.max(x, axis=0)


def test_an_option_xla_does_not_know_is_refused():
    assert not _compile._accepted({"xla_no_such_option_tactojax": True})


@pytest.mark.skipif(jax.default_backend() != "cpu" or COMPILER_OPTIONS is None,
                    reason="the option is XLA:CPU's, and this XLA does not know it")
def test_no_library_fusion_where_jax_jit_makes_one():
    x = jnp.linspace(0.0, 3.0, 64 * 64).reshape(64, 64)
    default = jax.jit(_reduction).lower(x, 2.0).compile().as_text()
    ours = top_level_jit(_reduction).lower(x, 2.0).compile().as_text()
    if "__ynn_fusion" not in default:
        pytest.skip("this XLA:CPU makes no library fusion here")
    assert "__ynn_fusion" not in ours


def test_same_values_as_jax_jit_and_static_arguments_work():
    x = jnp.linspace(-2.0, 2.0, 32 * 48).reshape(32, 48)
    static = functools.partial(top_level_jit, static_argnames=("scale",))(_reduction)
    np.testing.assert_allclose(static(x, scale=3.0), jax.jit(_reduction, static_argnames=("scale",))(x, scale=3.0),
                               rtol=1e-6, atol=1e-6)


def test_inside_a_users_jit_vmap_and_grad_it_runs_as_a_plain_jit():
    doubled = top_level_jit(lambda x: 2.0 * jnp.sum(x ** 2))
    x = jnp.arange(4.0)
    assert float(doubled(x)) == 28.0
    assert float(jax.jit(lambda y: doubled(y) + 1.0)(x)) == 29.0  # traced argument
    assert float(jax.jit(lambda y: doubled(x) + y)(1.0)) == 29.0  # a constant argument, nested
    np.testing.assert_allclose(jax.vmap(doubled)(jnp.stack([x, x])), [28.0, 28.0])
    np.testing.assert_allclose(jax.grad(doubled)(x), 4.0 * x)
    assert doubled._cache_size() >= 1
