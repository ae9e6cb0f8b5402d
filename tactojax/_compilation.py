"""Counting XLA compilations, to check that a loop never recompiles."""

from __future__ import annotations

import logging

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
