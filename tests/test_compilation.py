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


CACHE_SCRIPT = """
import sys
import jax, jax.numpy as jnp
from tactojax import use_compilation_cache
path = use_compilation_cache(None if sys.argv[1] == "default" else sys.argv[1], min_compile_time_s=0.0)
jax.jit(lambda x: jnp.sin(x) * 2.0 + 1.0)(jnp.ones(3)).block_until_ready()
print(path)
"""


def _run_cache_script(argument, tmp_path, **env):
    import os
    import subprocess
    import sys

    environment = {k: v for k, v in os.environ.items() if not k.startswith("JAX_") and k != "TACTOJAX_COMPILATION_CACHE"}
    environment.update(HOME=str(tmp_path / "home"), XDG_CACHE_HOME="", **env)
    result = subprocess.run([sys.executable, "-c", CACHE_SCRIPT, argument], env=environment, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return result.stdout.strip().splitlines()[-1]


def test_compilation_cache_keeps_programs_where_asked_and_nowhere_when_off(tmp_path):
    folder = tmp_path / "cache"
    assert _run_cache_script(str(folder), tmp_path) == str(folder)
    assert any(folder.iterdir()), "no compiled program was written"
    # By default under the user's cache folder; the variable picks another, or none.
    default = tmp_path / "home" / ".cache" / "tactojax" / "xla"
    assert _run_cache_script("default", tmp_path) == str(default) and any(default.iterdir())
    chosen = tmp_path / "chosen"
    assert _run_cache_script("default", tmp_path, TACTOJAX_COMPILATION_CACHE=str(chosen)) == str(chosen)
    assert _run_cache_script("default", tmp_path / "other", TACTOJAX_COMPILATION_CACHE="off") == "None"
    assert not (tmp_path / "other").exists()
    # A cache JAX was given already is kept.
    assert _run_cache_script(str(folder), tmp_path, JAX_COMPILATION_CACHE_DIR=str(chosen)) == str(chosen)
