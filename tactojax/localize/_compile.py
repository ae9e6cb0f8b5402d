"""How the localization stage's top-level programs are compiled: :func:`top_level_jit`, ``jax.jit``
without XLA:CPU's YNNPACK library fusions.

A localization program is thousands of small operations: a belief update refines 32 hypotheses
by 10 ICP iterations, each a few sums over a few hundred points, and loops over the touches it
holds. XLA:CPU (jaxlib 0.10) hands reductions and element-wise fusions to the YNNPACK library,
whose fixed cost per call outweighs the work at these sizes. Compiled without them
(``xla_cpu_experimental_ynn_fusion_type`` empty: XLA's own fused loops), on 2 CPU cores
(``benchmarks/belief_speed.py``, the scissors' 10 mm map, 8 episodes of new grasps, both in one
process): a belief update 13.2 ms for a first touch and 32.1 ms for a further one, against 20.7
and 42.0 ms with them. The networks (heightmap, features) keep them: their convolutions and
matrix products gain from the library (the heightmap 1.7-1.9 ms with, 2.6-3.1 ms without).

The option is a compiler option of each program, not a process-wide flag, so importing
tactojax changes nothing else a user compiles. JAX takes compiler options only on the outermost
``jit`` (a nested one raises), so a function compiled by :func:`top_level_jit` carries them only
when it is called at the top level: called with traced arguments (inside a user's ``jit``,
``vmap`` or ``grad``), or refused as nested, it runs as a plain ``jax.jit`` and takes whatever
options its caller's program has. An XLA that does not know the option (older or later jaxlib,
another backend that rejects it) compiles with its defaults.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

_WITHOUT_LIBRARY_FUSIONS = {"xla_cpu_experimental_ynn_fusion_type": ""}


def _accepted(options: dict[str, Any]) -> bool:
    """Whether the installed XLA compiles a program with ``options`` (once, at import)."""
    try:
        jax.jit(lambda x: x + 1, compiler_options=options).lower(jnp.float32(0)).compile()
    except Exception:  # an option this XLA does not know: INVALID_ARGUMENT (the type varies by version)
        return False
    return True


COMPILER_OPTIONS: dict[str, Any] | None = _WITHOUT_LIBRARY_FUSIONS if _accepted(_WITHOUT_LIBRARY_FUSIONS) else None
"""The XLA compiler options of every localization program (None: XLA's defaults)."""


class _TopLevelJit:
    """A jitted function compiled with :data:`COMPILER_OPTIONS` where it is the top-level program,
    and as a plain ``jax.jit`` inside another transformation (see the module docstring)."""

    def __init__(self, fun: Callable, **options: Any):
        self._plain = jax.jit(fun, **options)
        self._tuned = jax.jit(fun, compiler_options=COMPILER_OPTIONS, **options) if COMPILER_OPTIONS else self._plain
        functools.update_wrapper(self, fun)

    def __call__(self, *args, **kwargs):
        if self._tuned is self._plain or any(isinstance(leaf, jax.core.Tracer)
                                             for leaf in jax.tree.leaves((args, kwargs))):
            return self._plain(*args, **kwargs)
        try:
            return self._tuned(*args, **kwargs)
        except ValueError as error:  # inside another jit, called with constants only
            if "top-level" not in str(error):
                raise
            return self._plain(*args, **kwargs)

    def lower(self, *args, **kwargs):
        """``jax.jit(...).lower``, with :data:`COMPILER_OPTIONS` (for ahead-of-time compilation)."""
        return self._tuned.lower(*args, **kwargs)

    def _cache_size(self) -> int:
        """Programs compiled so far, both kinds (recompilation checks)."""
        tuned = self._tuned._cache_size()
        return tuned if self._tuned is self._plain else tuned + self._plain._cache_size()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._plain, name)


def top_level_jit(fun: Callable, /, **options: Any) -> Any:
    """``jax.jit(fun, **options)``, compiled with :data:`COMPILER_OPTIONS` when called as the
    top-level program (a decorator too, with ``functools.partial(top_level_jit,
    static_argnames=...)``)."""
    return _TopLevelJit(fun, **options)
