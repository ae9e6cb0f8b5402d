"""Counting XLA compilations, to check that a loop never recompiles."""

from __future__ import annotations

import logging
import re

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
