"""Batched evaluation sharded over devices: a mesh with one ``batch`` axis (DESIGN.md, "Scale").

An evaluation is a compiled program ``program(shared, batch)``: ``shared`` (the map, settings'
arrays) is replicated on every device, ``batch`` (episodes, touches, queries) is split along its
leading axis. Inside the program, :func:`over_batch` runs the per-device function on each
device's slice with ``jax.shard_map`` (no communication: every device computes what one device
would on its slice, :func:`in_batches` of a fixed size). :func:`run_sharded` pads the batch to a
multiple of the chunk (devices x items per device; copies of the last item), places every chunk with
``NamedSharding(mesh, PartitionSpec("batch"))``, calls the program once per chunk (the same
shapes: one compilation), shows progress per chunk and drops the padding. A chunk's shape depends
on the batch size and the devices only, never on how many items there are: evaluations of sets of
any size (a calibration set, then a test set) share one compilation.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from tqdm.auto import tqdm

BATCH_AXIS = "batch"
"""The mesh axis the batch is split over."""


def batch_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A one-axis mesh (``batch``) over ``devices`` (default: every local device)."""
    devices = jax.local_devices() if devices is None else list(devices)
    if not devices:
        raise ValueError("no devices to shard the batch over")
    return Mesh(np.asarray(devices), (BATCH_AXIS,))


def over_batch(local: Callable, mesh: Mesh) -> Callable:
    """``local(shared, batch)`` run on every device of ``mesh`` on its slice of ``batch``'s
    leading axis, ``shared`` replicated; the outputs concatenated along their leading axis.
    Called inside the jitted program (``mesh`` is one of its static arguments)."""
    return jax.shard_map(local, mesh=mesh, in_specs=(PartitionSpec(), PartitionSpec(BATCH_AXIS)),
                         out_specs=PartitionSpec(BATCH_AXIS), check_vma=False)


def in_batches(one: Callable, items, batch_size: int):
    """``one`` over the leading axis of ``items``, ``batch_size`` at a time (vmapped); 1: one at a
    time, unbatched. Each item's result depends on ``batch_size`` alone (up to rounding, a vmapped
    program can differ from an unbatched one), never on how many items or devices there are."""
    if batch_size == 1:
        return jax.lax.map(one, items)
    return jax.lax.map(one, items, batch_size=batch_size)


def run_sharded(program: Callable, shared, batch, *, mesh: Mesh, per_device: int, bar: tqdm | None = None):
    """``program(shared, chunk)`` over ``batch``, ``per_device`` items per device and call.

    Args:
        program: the jitted program (its mesh bound), returning a pytree of arrays with the
            chunk's leading axis.
        shared: replicated inputs (the map).
        batch: a pytree whose leaves share one leading axis of size N >= 1.
        mesh: :func:`batch_mesh`.
        per_device: items a device computes per call (the chunk's shape: one compilation).
        bar: a progress bar, advanced per chunk.

    Returns:
        ``program``'s outputs for the N items, as numpy arrays (the padding dropped).
    """
    count = jax.tree.leaves(batch)[0].shape[0]
    chunk = mesh.devices.size * per_device
    padding = -count % chunk
    if padding:
        batch = jax.tree.map(lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], padding, axis=0)]), batch)
    shared = jax.device_put(shared, NamedSharding(mesh, PartitionSpec()))
    split = NamedSharding(mesh, PartitionSpec(BATCH_AXIS))
    outputs = []
    for start in range(0, count + padding, chunk):
        piece = jax.device_put(jax.tree.map(lambda x: x[start:start + chunk], batch), split)
        outputs.append(jax.device_get(program(shared, piece)))
        if bar is not None:
            bar.update(min(chunk, count - start))
    return jax.tree.map(lambda *x: np.concatenate(x)[:count], *outputs)
