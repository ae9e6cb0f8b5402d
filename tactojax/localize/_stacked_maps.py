"""Every map of a catalog in one structure, without padding each map to the largest.

One compiled program serves every map only if every map has the same array shapes. Padding each
map to the largest map's imprints and surface grid does that, at the cost of memory: over the 79
maps of ``map-catalog ... ycb:all`` (20 mm grid) the padded maps took 4.46 GB, 256 kB per imprint
for maps of 42-58 kB per imprint on their own, since most maps are a fraction of the largest.

:class:`StackedMaps` instead concatenates the maps. Its per-imprint arrays hold every map's
imprints one after the other (the largest map last); a map is a *window* of ``window_size``
imprints (the largest map's count) starting at its own offset, the imprints past its own count
switched off. Its surfaces' stored
blocks are concatenated into one array, and their block grids (each map's own size) into one flat
index, read through each map's grid dimensions as data. :meth:`StackedMaps.view` cuts a map's
window inside jit, so a program compiled once takes ``(stack, index)`` for any map, and the
memory held is the maps' own.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Int

from tactojax import _struct as struct
from tactojax.localize._compile import top_level_jit
from tactojax.localize._map import BeliefCalibration, LocalizationMap
from tactojax.localize._surface import MapSurface

_PER_MAP = ("surface", "symmetries", "symmetry_axis", "symmetry_centre", "calibration")
"""The fields of a :class:`~tactojax.localize.LocalizationMap` that are the map's, not its imprints'."""


@struct.dataclass
class StackedMaps:
    """M maps in one structure (see the module docstring); ``len(stack)`` maps.

    Build it with :meth:`from_maps`; read map ``m`` with :meth:`view` (inside jit: a window of
    the shared arrays, every map the same shapes) or :meth:`map` (on the host: the map as it was
    given).
    """

    imprints: LocalizationMap
    """Every map's imprints one after the other, the largest map last (N rows, the maps' own),
    in a map whose per-map fields are None (they are below)."""
    offsets: Int[Array, "M"]
    """First row of each map in ``imprints``."""
    counts: Int[Array, "M"]
    """Imprints of each map."""
    blocks: jax.Array
    """(B, C, C, C) every map's stored surface blocks (:class:`~tactojax.localize.MapSurface`),
    block 0 the unknown one they share."""
    block_index: Int[Array, "L"]
    """Every map's block grid, flat and row-major, one after the other, the largest last
    (indices into ``blocks``)."""
    index_offsets: Int[Array, "M"]
    """Where each map's grid starts in ``block_index``."""
    grids: Int[Array, "M 3"]
    """Blocks along each axis of each map's grid."""
    origins: jax.Array
    """(M, 3) object-frame position of each map's grid cell (0, 0, 0), mm."""
    symmetries: jaxlie.SE3
    """(M, S) each map's symmetric copies, padded with identities to the most (a copy of the
    identity changes no distance up to symmetry)."""
    symmetry_axis: jax.Array
    """(M, 3) each map's continuous symmetry axis (zeros for none)."""
    symmetry_centre: jax.Array
    """(M, 3) a point on it, mm."""
    calibration: BeliefCalibration
    """Each map's belief calibration, stacked (M,)."""
    window_size: int = struct.field(pytree_node=False)
    """Imprints in every map's view: the largest map's count."""
    index_window_size: int = struct.field(pytree_node=False)
    """Entries of ``block_index`` in every map's view: the largest map's grid."""
    pitch_mm: float = struct.field(pytree_node=False)
    """The surfaces' grid step, mm."""

    def __len__(self) -> int:
        return int(self.offsets.shape[0])

    @staticmethod
    def from_maps(maps: Sequence[LocalizationMap]) -> StackedMaps:
        """The stack of ``maps`` (on the host; no program per map size).

        Raises:
            ValueError: no map, or the maps differ in what one program cannot take (pixel pitch,
                surface pitch, feature size, image size).
        """
        maps = list(maps)
        if not maps:
            raise ValueError("a map stack needs at least one map")
        for name, value in (("mm_per_px", lambda v: v.mm_per_px), ("surface pitch", lambda v: v.surface.pitch_mm),
                            ("feature size", lambda v: v.features.shape[1]),
                            ("points per imprint", lambda v: v.points.shape[1]),
                            ("image size", lambda v: v.packed_heightmaps.shape[1:])):
            if len({value(v) for v in maps}) > 1:
                raise ValueError(f"the maps differ in {name} ({[value(v) for v in maps]}): one stack cannot hold them")
        counts = np.array([len(v) for v in maps], np.int32)
        window = int(counts.max())
        # Laid out with the largest map last: every map's window then lies within the arrays, no padding.
        layout, offsets = _largest_last(counts)
        rows = [_imprint_fields(maps[m]) for m in layout]
        imprints = jax.tree.map(lambda *x: jnp.asarray(np.concatenate([np.asarray(a) for a in x])), *rows)
        blocks, index, index_offsets, grids = _concatenated_surfaces([v.surface for v in maps])
        if blocks.size >= 2**31 or index.size >= 2**31:  # read through int32 indices
            raise ValueError(f"the maps' surfaces hold {blocks.size:,} cells in {index.size:,} grid blocks: more than "
                             "one stack can index (2**31); split the catalog")
        copies = max(v.symmetries.wxyz_xyz.shape[0] for v in maps)
        identity = np.asarray(jaxlie.SE3.identity().wxyz_xyz)
        symmetries = np.stack([np.concatenate([np.asarray(v.symmetries.wxyz_xyz),
                                               np.broadcast_to(identity, (copies - v.symmetries.wxyz_xyz.shape[0], 7))])
                               for v in maps])
        stack = lambda *x: jnp.asarray(np.stack([np.asarray(a) for a in x]))  # noqa: E731
        return StackedMaps(
            imprints=imprints, offsets=jnp.asarray(offsets),
            counts=jnp.asarray(counts), blocks=jnp.asarray(blocks), block_index=jnp.asarray(index),
            index_offsets=jnp.asarray(index_offsets), grids=jnp.asarray(grids),
            origins=stack(*(v.surface.origin for v in maps)), symmetries=jaxlie.SE3(jnp.asarray(symmetries)),
            symmetry_axis=stack(*(v.symmetry_axis for v in maps)),
            symmetry_centre=stack(*(v.symmetry_centre for v in maps)),
            calibration=jax.tree.map(stack, *(v.calibration for v in maps)),
            window_size=window, index_window_size=int(np.prod(grids, axis=1).max()), pitch_mm=float(maps[0].surface.pitch_mm))

    def view(self, index: int | Int[Array, ""]) -> LocalizationMap:
        """Map ``index`` as a :class:`~tactojax.localize.LocalizationMap` of ``window_size`` imprints,
        the same shapes for every map (jit-compatible; ``index`` may be traced).

        Its imprints past the map's own count are switched off (``imprint_valid``, their
        points, features and poses cleared as :meth:`~tactojax.localize.LocalizationMap.padded_to`
        clears them; their heightmaps, which nothing reads without them, are left as they are).
        Every number computed from the view equals that computed from the map padded to ``window_size``.
        """
        start, count = self.offsets[index], self.counts[index]
        own = jnp.arange(self.window_size) < count
        cut = jax.tree.map(lambda x: jax.lax.dynamic_slice_in_dim(x, start, self.window_size), self.imprints)
        poses = jnp.where(own[:, None], cut.T_object_sensor.wxyz_xyz, jaxlie.SE3.identity().wxyz_xyz)
        surface = MapSurface(blocks=self.blocks, origin=self.origins[index], pitch_mm=self.pitch_mm,
                             block_index=jax.lax.dynamic_slice_in_dim(self.block_index, self.index_offsets[index],
                                                                      self.index_window_size),
                             grid=self.grids[index])
        return cut.replace(
            T_object_sensor=jaxlie.SE3(poses), openings=jnp.where(own, cut.openings, 0),
            features=jnp.where(own[:, None], cut.features, 0), imprint_valid=cut.imprint_valid & own,
            points=jnp.where(own[:, None, None], cut.points, 0), normals=jnp.where(own[:, None, None], cut.normals, 0),
            points_valid=cut.points_valid & own[:, None], centres=jnp.where(own[:, None], cut.centres, 0),
            surface=surface, symmetries=jaxlie.SE3(self.symmetries.wxyz_xyz[index]),
            symmetry_axis=self.symmetry_axis[index], symmetry_centre=self.symmetry_centre[index],
            calibration=jax.tree.map(lambda x: x[index], self.calibration))

    def window(self, index: int) -> LocalizationMap:
        """:meth:`view` from the host, its per-imprint arrays its own (one compiled program for
        every map) and its surface reading the stack's shared blocks: for programs that take a
        map, one map at a time.

        Raises:
            IndexError: ``index`` is not a map of the stack.
        """
        view = _view_without_blocks(self, np.int32(self._checked(index)))
        return view.replace(surface=view.surface.replace(blocks=self.blocks))

    def map(self, index: int) -> LocalizationMap:
        """Map ``index`` on its own (on the host): its imprints, and its surface on its own grid
        holding the blocks it reads (trailing identity copies of its symmetries and stored blocks
        that nothing pointed to, which padding adds, are left out). For host code: figures, the
        marching grid of active touch, a program compiled for one map.

        Raises:
            IndexError: ``index`` is not a map of the stack.
        """
        index = self._checked(index)
        start, count = int(self.offsets[index]), int(self.counts[index])
        own = jax.tree.map(lambda x: jnp.asarray(np.asarray(x)[start:start + count]), self.imprints)
        grid = tuple(int(n) for n in np.asarray(self.grids[index]))
        first = int(self.index_offsets[index])
        flat = np.asarray(self.block_index[first:first + int(np.prod(grid))]).reshape(grid)
        slots = np.unique(np.concatenate([[0], flat.ravel()]))  # the unknown block first, as a map's own
        surface = MapSurface(blocks=jnp.asarray(np.asarray(self.blocks)[slots]),
                             block_index=jnp.asarray(np.searchsorted(slots, flat).astype(np.int32)),
                             origin=self.origins[index], pitch_mm=self.pitch_mm)
        copies = np.asarray(self.symmetries.wxyz_xyz[index])
        identity = np.asarray(jaxlie.SE3.identity().wxyz_xyz)
        keep = 1 + int(np.max(np.flatnonzero(np.any(np.abs(copies - identity) > 0, axis=1)), initial=0))
        return own.replace(surface=surface, symmetries=jaxlie.SE3(jnp.asarray(copies[:keep])),
                           symmetry_axis=self.symmetry_axis[index], symmetry_centre=self.symmetry_centre[index],
                           calibration=jax.tree.map(lambda x: x[index], self.calibration))

    def _checked(self, index) -> int:
        """``index`` as a host int, refused outside the stack (inside jit an index out of range
        would read another map: JAX clamps gathers)."""
        if not 0 <= int(index) < len(self):
            raise IndexError(f"map {int(index)} of a stack of {len(self)} maps")
        return int(index)

    def with_calibration(self, calibration: BeliefCalibration) -> StackedMaps:
        """The same stack with one calibration for every map (beliefs that compare: P(object))."""
        return self.replace(calibration=jax.tree.map(
            lambda x: jnp.broadcast_to(jnp.asarray(x, jnp.float32), (len(self),)), calibration))

    @property
    def nbytes(self) -> int:
        """Bytes of every array the stack holds."""
        return int(sum(leaf.nbytes for leaf in jax.tree.leaves(self)))


@top_level_jit
def _view_without_blocks(stack: StackedMaps, index: Int[Array, ""]) -> LocalizationMap:
    """A map's view without its surface's blocks (:meth:`StackedMaps.window` attaches the stack's
    own after: a program's outputs are new arrays, and the blocks are the stack's largest)."""
    view = stack.view(index)
    return view.replace(surface=view.surface.replace(blocks=None))


def _imprint_fields(view: LocalizationMap) -> LocalizationMap:
    """The map with only its per-imprint fields (the per-map ones None), poses as plain arrays."""
    return view.replace(T_object_sensor=jaxlie.SE3(view.T_object_sensor.wxyz_xyz),
                        **{name: None for name in _PER_MAP})


def _largest_last(sizes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How to lay out items of ``sizes`` one after the other: the order (as given, but the
    largest last: a window of the largest size from any item's start then ends within the
    items), and each item's start (int32, in the given order)."""
    largest = int(np.argmax(sizes))
    order = np.array([i for i in range(len(sizes)) if i != largest] + [largest])
    starts = np.zeros(len(sizes), np.int32)
    starts[order] = np.concatenate([[0], np.cumsum(np.asarray(sizes)[order])[:-1]])
    return order, starts


def _concatenated_surfaces(surfaces: Sequence[MapSurface]):
    """Every surface's stored blocks in one array (the shared unknown block first) and their
    block grids in one flat index of slots into it (the largest grid last, so that an index
    window of its size from any grid's start lies within it); with each grid's start in the
    index and its blocks per axis."""
    if any(surface.grid is not None for surface in surfaces):
        raise ValueError("a stack's maps must hold their own surfaces (StackedMaps.map gives them)")
    grids = np.array([surface.block_index.shape for surface in surfaces], np.int32)
    order, starts = _largest_last(np.prod(grids, axis=1))
    blocks, index, stored = [np.asarray(surfaces[0].blocks)[:1]], [], 1
    for m in order:
        own, grid = np.asarray(surfaces[m].blocks), np.asarray(surfaces[m].block_index)
        blocks.append(own[1:])
        index.append(np.where(grid > 0, grid - 1 + stored, 0).astype(np.int32).ravel())
        stored += own.shape[0] - 1
    return np.concatenate(blocks), np.concatenate(index), starts, grids
