"""Counting XLA compilations (to check that a loop never recompiles), and keeping them between
runs (:func:`use_compilation_cache`)."""

from __future__ import annotations

import logging
import os
import re
from pathlib import Path

import jax


class CompilationCounter(logging.Handler):
    """Counts the XLA compilations that happen inside a ``with`` block.

    jax logs one "Compiling ..." message per compilation when ``jax_log_compiles`` is on; the
    counter turns it on for the block, listens to jax's logger, and restores both on exit::

        with CompilationCounter() as compiles:
            for frame in frames:
                localizer(frame, opening)
        assert compiles.count == 0
    """

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.messages: list[str] = []
        """jax's log line of each compilation (names the function and its argument shapes)."""
        self._previous = None

    @property
    def count(self) -> int:
        """Compilations so far."""
        return len(self.messages)

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if "Compiling" in message:
            self.messages.append(message)

    def __enter__(self) -> CompilationCounter:
        self._previous = jax.config.jax_log_compiles
        jax.config.update("jax_log_compiles", True)
        logging.getLogger("jax").addHandler(self)
        return self

    def __exit__(self, *exc_info) -> None:
        logging.getLogger("jax").removeHandler(self)
        jax.config.update("jax_log_compiles", self._previous)


FREE_OPS = frozenset({"parameter", "constant", "tuple", "get-tuple-element", "bitcast", "after-all", "partition-id",
                      "replica-id"})
"""Top-level HLO instructions that launch no kernel (views and bookkeeping)."""


_OPCODE = re.compile(r"\s([a-z][\w.-]*)\(")
"""The opcode of an HLO instruction: the first lower-case word followed by its operand list."""


def kernel_count(compiled: jax.stages.Compiled) -> int:
    """Kernels one call of a compiled program launches: top-level instructions of its optimized HLO.

    XLA's CPU and GPU runtimes run each instruction of the entry computation (a fusion, a
    library call such as a convolution, dot or FFT, a sort, a loop) as one kernel or thunk; a
    ``while`` loop counts once here, though its body runs once per iteration. On a CPU the
    fixed cost per kernel dominates programs of many small ones (jax#40150), so fewer is faster.

        compiled = jax.jit(f).lower(*args).compile()
        print(kernel_count(compiled))
    """
    count, in_entry = 0, False
    for line in compiled.as_text().splitlines():
        if line.startswith("ENTRY "):
            in_entry = True
            continue
        if in_entry:
            if line.startswith("}"):
                break
            if "=" not in line:
                continue
            # "%name = SHAPE opcode(operands), ...": SHAPE may be a tuple "(f32[2], s32[])".
            match = _OPCODE.search(line.split("=", 1)[1])
            count += match is not None and match.group(1) not in FREE_OPS
    return count


CACHE_VARIABLE = "TACTOJAX_COMPILATION_CACHE"
"""Environment variable: the folder :func:`use_compilation_cache` keeps compiled programs in, or
``off`` for none."""


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/tactojax/xla`` (``~/.cache/tactojax/xla`` by default)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "tactojax" / "xla"


def use_compilation_cache(path: str | Path | None = None, *, min_compile_time_s: float = 1.0) -> Path | None:
    """Keep compiled XLA programs on disk (JAX's persistent compilation cache), so that the next
    process that builds the same programs loads them instead of compiling: the live
    :class:`~tactojax.localize.Localizer` on a CPU compiles for 10-60 s at start-up, every start.

    The ``tactojax`` command calls this before every sub-command; call it yourself at the top of
    a script or notebook. JAX checks each entry against the program, the jaxlib version and the
    device, so a stale entry is never used. Nothing changes where a cache is set already (JAX's
    ``jax_compilation_cache_dir``, or ``JAX_COMPILATION_CACHE_DIR``).

    Args:
        path: the folder; default: ``$TACTOJAX_COMPILATION_CACHE``, else :func:`default_cache_dir`.
            ``"off"`` (or that variable set to ``off``) keeps no cache.
        min_compile_time_s: programs that compile faster than this are not kept (the many tiny
            ones would only fill the folder).

    Returns:
        the folder in use (None: no cache).
    """
    current = jax.config.jax_compilation_cache_dir
    if current:
        return Path(current)
    if path is None:
        path = os.environ.get(CACHE_VARIABLE) or default_cache_dir()
    if str(path) == "off":
        return None
    path = Path(path).expanduser()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:  # a read-only home: run without a cache, saying why
        logging.getLogger(__name__).warning(f"no compilation cache: cannot create {path} ({error})")
        return None
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_time_s))
    return path
