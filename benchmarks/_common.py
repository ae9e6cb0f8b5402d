"""Shared helpers for the benchmark scripts: the flags, the cached maps, machine info, timing,
tables and JSON output.

Flags: every script takes ``--json PATH``, ``--quick`` (a smoke run of a minute or two) and
``--seed`` (:func:`add_common_arguments`); a script that times repeated calls takes ``--repeats``.
A script that needs a map takes saved maps as positional arguments, or ``--object`` to simulate
and map one once under ``--work`` and read it from there afterwards (:func:`add_map_arguments`,
:func:`load_maps`; ``--quick`` maps on a coarser grid).

Timing convention (see STYLE.md, Benchmarks): the first call of a jitted function includes
tracing and XLA compilation; it is reported apart from the steady state, which is the median of
``repeats`` further calls. Every call ends with ``jax.block_until_ready`` so that JAX's
asynchronous dispatch does not hide work.
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import statistics
import sys
import time
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax

from tactojax.cli import format_table as _format_table
from tactojax.cli import write_json as write_json
from tactojax.features import encode_images
from tactojax.io import (DEFAULT_ENCODER, catalog_slug, load_tactile_map, read_grasps, save_tactile_map,
                         stored_features_encoder, tactile_map_metadata)
from tactojax.localize import calibration_from_json
from tactojax.mapping import build_tactile_map
from tactojax.objects import get_object
from tactojax.sensor import gelslim
from tactojax.simulate import GraspsProtocol, MappingProtocol, simulate_to_dataset

WORK = "benchmark-data/maps"
"""Where simulated datasets and the maps built from them are cached (relative to the working directory)."""
DEFAULT_MODEL = "bundled:fast-gelslim-0.5"
"""The shape model of every script that predicts heightmaps (the bundled one, gelslim at half resolution)."""
GRID_MM, QUICK_GRID_MM = 10.0, 20.0
"""The mapping grid of a simulated map (the paper's), and of ``--quick`` runs, mm."""

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


# --- flags ---------------------------------------------------------------------------------------

def add_common_arguments(parser: argparse.ArgumentParser, *, quick: str, seed: int = 0, seed_help: str = "",
                         repeats: int | None = None, repeats_help: str = "steady-state calls per timing") -> None:
    """``--json PATH``, ``--quick`` (its help: what it shrinks), ``--seed`` and, for a script that
    times repeated calls, ``--repeats`` (default ``repeats``)."""
    parser.add_argument("--json", metavar="PATH", help="write the results as JSON here")
    parser.add_argument("--quick", action="store_true", help=f"smoke run: {quick}")
    parser.add_argument("--seed", type=int, default=seed,
                        help=f"{seed_help or 'random draws of the run'} (default {seed})")
    if repeats is not None:
        parser.add_argument("--repeats", type=int, default=repeats, help=f"{repeats_help} (default {repeats})")


def add_map_arguments(parser: argparse.ArgumentParser, *, several: bool = False) -> None:
    """Saved maps as positional arguments (``several``: any number, else at most one), or
    ``--object`` to simulate and map (once, cached under ``--work``); ``--model``, ``--encoder``."""
    parser.add_argument("maps", nargs="*" if several else "?", metavar="MAP",
                        help="saved tactile map(s) (.npz); default: simulate and map --object")
    parser.add_argument("--object", default="scissors", help="catalog object simulated and mapped without a MAP "
                                                             "(default scissors)")
    parser.add_argument("--work", default=WORK, help=f"simulated data and map cache (default {WORK})")
    parser.add_argument("--model", default=DEFAULT_MODEL, help=f"shape model (default {DEFAULT_MODEL})")
    parser.add_argument("--encoder", default=DEFAULT_ENCODER, help=f"retrieval encoder (default {DEFAULT_ENCODER})")


def map_paths(args: argparse.Namespace) -> list[str]:
    """The saved maps the command line names (``add_map_arguments``), as a list."""
    return [] if args.maps is None else [args.maps] if isinstance(args.maps, str) else list(args.maps)


# --- simulated data and cached maps --------------------------------------------------------------

def simulated(work, name: str, protocol, tag: str, *, seed: int = 0, scale: float = 0.5) -> Path:
    """A simulated dataset of ``protocol`` on catalog object ``name`` (gelslim at ``scale``),
    written once under ``work`` and read from there afterwards.

    The PRNG key comes from ``tag`` (which names the protocol's settings) and ``seed``: the same
    tag and seed give the same data, another seed other draws of the same protocol."""
    suffix = ("" if seed == 0 else f"-seed{seed}") + ("" if scale == 0.5 else f"-gelslim{scale:g}")
    path = Path(work) / f"{name}-{tag}{suffix}"
    if not (path / "manifest.json").exists():
        key = jax.random.key((zlib.crc32(tag.encode()) + seed) % 2**32)
        simulate_to_dataset(path, key, gelslim(scale=scale), get_object(name), protocol)
    return path


def mapping_grid(args: argparse.Namespace) -> float:
    """The mapping grid of a simulated map: the paper's 10 mm, 20 mm for ``--quick``."""
    return QUICK_GRID_MM if args.quick else GRID_MM


def object_map(work, name: str, model, model_name: str, encoder, encoder_name: str, *, grid_mm: float = GRID_MM,
               images: bool = False):
    """The tactile map of catalog object ``name`` with retrieval features: the mapping protocol
    simulated (:func:`simulated`), mapped by ``model`` and encoded by ``encoder`` once, saved
    under ``work`` and read from there afterwards (keyed by the object, grid, model and encoder
    names). One map for every script: ``--seed`` draws what a script does with it, not the map.
    ``images``: a cached map is read with its tactile images (a fresh one holds them anyway)."""
    tag = f"map-grid{grid_mm:g}"
    cached = Path(work) / f"{name}-{tag}-{catalog_slug(model_name)}-{catalog_slug(encoder_name)}.npz"
    if cached.exists():
        return load_tactile_map(cached, images=images)
    dataset = simulated(work, name, MappingProtocol(grid_mm=grid_mm), tag)
    grasps = read_grasps(dataset)
    tactile_map = build_tactile_map(model, grasps["images"], grasps["T_world_gripper"], grasps["openings"], name,
                                    T_world_object=grasps["T_world_object"])
    tactile_map = tactile_map.with_features(encode_images(encoder, tactile_map.stored_images(), progress=True))
    save_tactile_map(cached, tactile_map, metadata={"data": str(dataset), "model": model_name,
                                                    "features_encoder": encoder_name})
    return tactile_map


def saved_map(path, encoder, encoder_name: str, *, images: bool = False):
    """A saved map with features of ``encoder`` (those it stores when it says they come from
    that encoder, else encoded now) and its stored belief calibration when fit with that
    encoder (None: uncalibrated). ``images``: read its tactile images too."""
    tactile_map = load_tactile_map(path, images=images)
    header = tactile_map_metadata(path)
    metadata = header.get("metadata", {})
    stored = metadata.get("belief_calibration")
    # The features' encoder as the library reads it; caches written by object_map before it used
    # the library's key recorded it as ``encoder``.
    source = stored_features_encoder(header) or metadata.get("encoder")
    if tactile_map.features.shape[1] == 0 or source != encoder_name:  # encoded anew: the images are needed
        images = load_tactile_map(path, images=True).stored_images()
        tactile_map = tactile_map.with_features(encode_images(encoder, images, progress=True))
    usable = stored is not None and stored.get("encoder", encoder_name) == encoder_name
    return tactile_map, (calibration_from_json(stored) if usable else None)


def load_maps(args: argparse.Namespace, model, encoder, *, images: bool = False) -> list[tuple[Any, Any]]:
    """(map with features, belief calibration or None) for every map the command line names, or
    for ``--object`` simulated and mapped (:func:`object_map`, uncalibrated); with ``images``,
    the maps hold their tactile images."""
    paths = map_paths(args)
    if paths:
        return [saved_map(path, encoder, args.encoder, images=images) for path in paths]
    return [(object_map(args.work, args.object, model, args.model, encoder, args.encoder,
                        grid_mm=mapping_grid(args), images=images), None)]


def new_grasps_set(args: argparse.Namespace, name: str, *, episodes: int, grasps: int, fingers: int) -> Path:
    """``args.test``, or a new-grasps test set of ``name`` simulated once under ``args.work``."""
    if getattr(args, "test", None):
        return Path(args.test)
    return simulated(args.work, name, GraspsProtocol(episodes=episodes, grasps_per_episode=grasps, fingers=fingers),
                     f"grasps-e{episodes}-g{grasps}-f{fingers}", seed=args.seed)


def print_machine() -> None:
    """One line: JAX version, device and usable cores."""
    info = machine_info()
    print(f"JAX {info['jax_version']} on {info['jax_device_kind']}; {info['usable_cpus']} usable cores", flush=True)
