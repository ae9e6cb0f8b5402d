"""Shared helpers for the benchmark scripts: machine info, timing, tables and JSON output.

Timing convention (see STYLE.md, Benchmarks): the first call of a jitted function includes
tracing and XLA compilation; it is reported apart from the steady state, which is the median of
``repeats`` further calls. Every call ends with ``jax.block_until_ready`` so that JAX's
asynchronous dispatch does not hide work.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax


def machine_info() -> dict[str, Any]:
    """The machine, CPU count, Python/JAX versions, JAX backend and device, for the JSON record."""
    try:
        usable_cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not available on macOS/Windows
        usable_cpus = os.cpu_count()
    return {
        "machine": platform.machine(),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "hostname": platform.node(),
        "cpu_count": os.cpu_count(),
        "usable_cpus": usable_cpus,
        "python": sys.version.split()[0],
        "jax_version": jax.__version__,
        "jax_backend": jax.default_backend(),
        "jax_devices": [str(device) for device in jax.devices()],
        "jax_device_kind": jax.devices()[0].device_kind,  # e.g. "cpu", "NVIDIA H100 80GB HBM3"
    }


def time_call(fn: Callable[..., Any], *args: Any, repeats: int) -> dict[str, float]:
    """Time ``fn(*args)``: first call (compile + run) apart from the steady-state median.

    Returns:
        ``first_call_s`` (includes compilation), ``compile_s`` (first call minus the steady
        median, an estimate), ``median_s``, ``min_s`` over ``repeats`` steady calls, ``repeats``.
    """
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - start
    steady = []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        steady.append(time.perf_counter() - start)
    median = statistics.median(steady)
    return {
        "first_call_s": first,
        "compile_s": max(first - median, 0.0),
        "median_s": median,
        "min_s": min(steady),
        "repeats": len(steady),
    }


def format_table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A plain-text table with columns aligned (floats get 3 significant digits)."""

    def cell(value: Any) -> str:
        if isinstance(value, float):
            return f"{value:.3g}" if abs(value) < 1e4 else f"{value:.0f}"
        return "-" if value is None else str(value)

    text = [[str(h) for h in headers]] + [[cell(v) for v in row] for row in rows]
    widths = [max(len(line[i]) for line in text) for i in range(len(headers))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in text]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def write_json(path: str | os.PathLike[str], payload: dict[str, Any]) -> None:
    """Write ``payload`` as indented JSON, atomically where tactojax provides the helper."""
    data = (json.dumps(payload, indent=2, sort_keys=False) + "\n").encode("utf-8")
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        from tactojax.storage._atomic import atomic_write_bytes
    except ImportError:  # older tactojax: a plain write
        target.write_bytes(data)
    else:
        atomic_write_bytes(target, data)
