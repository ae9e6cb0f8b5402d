"""Shared helpers for the benchmark scripts: machine info, timing, tables and JSON output.

Timing convention (see STYLE.md, Benchmarks): the first call of a jitted function includes
tracing and XLA compilation; it is reported apart from the steady state, which is the median of
``repeats`` further calls. Every call ends with ``jax.block_until_ready`` so that JAX's
asynchronous dispatch does not hide work.
"""

from __future__ import annotations

import functools
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any

import jax

from tactojax.cli import format_table as _format_table
from tactojax.cli import write_json as write_json

format_table = functools.partial(_format_table, significant=3)
"""The CLI's table, floats with 3 significant digits (timings span seconds to microseconds)."""


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


def seconds_of(call: Callable[[], Any]) -> tuple[float, Any]:
    """(wall-clock seconds, result) of one ``call()``, its result ready (``block_until_ready``)."""
    start = time.perf_counter()
    out = jax.block_until_ready(call())
    return time.perf_counter() - start, out


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
