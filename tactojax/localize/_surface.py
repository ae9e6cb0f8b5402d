"""The whole map's surface as one signed-distance grid: where a touch fits, at any pose.

Every surface pixel a map stores (sampled from each imprint's whole predicted contact mask,
:attr:`~tactojax.mapping.TactileMap.surface_pixels`; the contact points of a map that keeps
none), placed in the object frame with its normal, that the gel felt deeper than
``min_depth_mm`` is a small planar sample of the object's surface. :func:`build_map_surface`
turns them into a dense grid over the object: at every cell within ``reach_mm`` of a stored
point, the *signed* distance from the cell to the tangent plane of its nearest stored point
(positive outside the object, along the stored normal; NaN farther away: the map says nothing
there).
A touch is then scored at any hypothesis by one trilinear look-up per point, the opposite
finger's touch and a touch that lands between stored imprints included, against the surface
that all the imprints felt together.

The grid is built once per map on the host (SciPy's k-d tree for the nearest stored point;
about 1-4 s for the catalog maps on 2 cores), and read inside jit. Only its known blocks are
stored (:class:`MapSurface`): at 0.5 mm pitch the catalog maps take 0.1-1 MB.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from tactojax import _struct as struct
from tactojax.mapping import TactileMap


def row_major_strides(shape):
    """(3,) int32 steps along each axis of a row-major 3-D grid of ``shape`` (a NumPy shape:
    NumPy strides; a traced one, a grid's dimensions as data: traced strides)."""
    if isinstance(shape, np.ndarray):
        return np.array([shape[1] * shape[2], shape[2], 1], np.int32)
    return jnp.stack([shape[1] * shape[2], shape[2], jnp.ones_like(shape[2])]).astype(jnp.int32)


@dataclass(frozen=True)
class SurfaceSettings:
    """How the surface grid is built (static)."""

    pitch_mm: float = 0.5
    """Grid step, mm."""
    reach_mm: float = 1.5
    """Cells farther than this from every stored point are unknown, mm."""
    margin_mm: float = 3.0
    """How far the grid extends beyond the stored points, mm."""
    min_depth_mm: float = 0.3
    """Stored points indented less than this are left out, mm. Around an edge the gel sags
    without touching (its skirt), and the shape model reports that sag as shallow contact: on
    the gum box 5.5 % of the stored points lay over 1 mm outside the object, every one of them
    indented 0.17-0.25 mm, and they widened each face past its edges by up to 3 mm. The
    likelihood's no-contact test trusts an indentation only beyond the same depth
    (``LikelihoodSettings.margin_mm``)."""


BLOCK = 4
"""Cells along each side of a block of the surface grid (4 x 4 x 4 cells, 2 mm at the default
pitch); a stored block also holds the first cells of its neighbours (5 x 5 x 5)."""

_BLOCK_BITS = BLOCK.bit_length() - 1
assert BLOCK == 1 << _BLOCK_BITS, "BLOCK must be a power of two"


@struct.dataclass
class MapSurface:
    """A signed-distance grid of the map's surface (see the module docstring), stored sparsely.

    Only the cells within ``reach_mm`` of a stored point are known, 1-12 % of a catalog map's
    grid (a shell around the surface). The grid is cut into blocks of :data:`BLOCK` cells a side,
    and only the blocks whose cells (with their neighbours' first ones, so that the eight corners
    of any cell lie in one stored block) hold a known distance are kept. A point reads its
    block's slot, then its cell's corners: about 10 % slower than a dense grid in the belief's
    update, for a tenth of the memory or less (a catalog map's surface from 22-410 kB per imprint
    to 5-35 kB). Stored blocks hold float32: int16 or float16 would halve them again, but
    converting what is read made the update 20-30 % slower on a CPU.
    """

    blocks: Float[Array, "N C C C"]
    """Signed distance (mm) from every cell centre of the kept blocks (``C = BLOCK + 1`` cells a
    side) to the surface: > 0 outside the object; NaN where no stored point lies within
    ``reach_mm``. Block 0 knows nothing (every block without a known cell points to it)."""
    block_index: Int[Array, "I J K"] | Int[Array, "L"]
    """Which of ``blocks`` holds each block of the grid (0: none known); flat, row-major, where
    ``grid`` is given."""
    origin: Float[Array, "3"]
    """Object-frame position of cell (0, 0, 0), mm."""
    pitch_mm: float = struct.field(pytree_node=False)
    """Grid step, mm."""
    grid: Int[Array, "3"] | None = None
    """Blocks along each axis when they are data, not ``block_index``'s shape: a map's surface
    within a :class:`~tactojax.localize.StackedMaps`, whose maps share one ``blocks`` array and
    one flat index (only :meth:`signed_distance` reads such a surface; None for a map's own)."""

    @staticmethod
    def from_dense(distance: Float[Array, "X Y Z"], origin: Float[Array, "3"], pitch_mm: float) -> MapSurface:
        """The sparse surface of a dense grid (host; NaN: unknown), extended with unknown cells
        to whole blocks."""
        dense = np.asarray(distance, np.float32)
        blocks_shape = -(-np.array(dense.shape) // BLOCK)
        side = BLOCK + 1
        padded = np.full(blocks_shape * BLOCK + 1, np.nan, np.float32)
        padded[tuple(slice(0, n) for n in dense.shape)] = dense
        # Every block with its neighbours' first cells: (I, J, K, C, C, C), strided views.
        stride = np.array(padded.strides)
        view = np.lib.stride_tricks.as_strided(padded, (*blocks_shape, side, side, side),
                                               (*(stride * BLOCK), *stride), writeable=False)
        kept = np.any(np.isfinite(view), axis=(3, 4, 5))
        index = np.zeros(blocks_shape, np.int32)
        index[kept] = np.arange(1, int(kept.sum()) + 1)
        blocks = np.concatenate([np.full((1, side, side, side), np.nan, np.float32), view[kept]])
        return MapSurface(blocks=jnp.asarray(blocks), block_index=jnp.asarray(index),
                          origin=jnp.asarray(origin, jnp.float32), pitch_mm=float(pitch_mm))

    @property
    def shape(self) -> tuple[int, int, int]:
        """Cells along each axis of the grid (whole blocks; a map's own surface only)."""
        if self.grid is not None:
            raise ValueError("a surface within a StackedMaps has no static shape: StackedMaps.map gives the map's own")
        return tuple(int(n) * BLOCK for n in self.block_index.shape)

    @property
    def distance(self) -> Float[Array, "X Y Z"]:
        """The dense grid (mm; NaN: unknown), for host code and figures."""
        cells = self.blocks[:, :BLOCK, :BLOCK, :BLOCK][self.block_index]  # (I, J, K, B, B, B)
        return cells.transpose(0, 3, 1, 4, 2, 5).reshape(self.shape)

    def padded_to(self, blocks_shape: tuple[int, int, int], count: int) -> MapSurface:
        """The surface on a grid of ``blocks_shape`` blocks (extended on its far sides with
        unknown ones) holding ``count`` blocks (unknown ones added): maps padded to one shape
        compile once."""
        if self.grid is not None:
            raise ValueError("a surface within a StackedMaps cannot be padded: StackedMaps.map gives the map's own")
        # On the host: no program per map size.
        index = np.pad(np.asarray(self.block_index), [(0, n - m) for n, m in zip(blocks_shape, self.block_index.shape)])
        blocks = np.asarray(self.blocks)
        extra = np.broadcast_to(blocks[:1], (count - blocks.shape[0], *blocks.shape[1:]))
        return self.replace(blocks=jnp.asarray(np.concatenate([blocks, extra])), block_index=jnp.asarray(index))

    def signed_distance(self, p_object: Float[Array, "*batch 3"], *, interpolate: bool = True
                        ) -> tuple[Float[Array, "*batch"], Bool[Array, "*batch"]]:
        """Signed distance (mm) and whether it is known at object-frame points ``p_object``.

        With ``interpolate``, trilinear over the known corners of the point's cell (weights
        renormalised; known where any corner is, inside the grid); without, the nearest cell's
        value (one corner instead of eight: for screening thousands of coarse candidates, off
        by up to ``pitch_mm * sqrt(3) / 2`` in position). Unknown distances read 0.
        """
        # Static for a map's own surface; data within a stack (the same arithmetic, traced).
        grid = np.array(self.block_index.shape) if self.grid is None else self.grid
        shape, strides = grid * BLOCK, row_major_strides(grid)
        side = BLOCK + 1
        in_block = np.array([side * side, side, 1], np.int32)  # a cell's step along each axis of a stored block
        cell = (p_object - self.origin) / self.pitch_mm
        inside = jnp.all((cell >= 0) & (cell <= shape - 1), axis=-1)
        last = shape - (2 if interpolate else 1)  # the cell whose corners are read, at most
        low = jnp.clip(jnp.floor(cell) if interpolate else jnp.round(cell), 0, last).astype(jnp.int32)
        # low >= 0 and BLOCK a power of two: shifts and masks (integer division is slow on a CPU).
        block, within = low >> _BLOCK_BITS, low & (BLOCK - 1)
        slot = self.block_index.reshape(-1)[block @ strides]
        base = slot * side**3 + within @ in_block  # the cell, in its block
        corners = np.array(list(np.ndindex(2, 2, 2))) if interpolate else np.zeros((1, 3), int)
        stored = self.blocks.reshape(-1)[base[..., None] + corners @ in_block]
        finite = jnp.isfinite(stored)
        values = jnp.where(finite, stored, 0.0)
        if not interpolate:
            known = inside & finite[..., 0]
            return jnp.where(known, values[..., 0], 0.0), known
        fraction = jnp.clip(cell - low, 0.0, 1.0)
        weights = jnp.prod(jnp.where(corners == 1, fraction[..., None, :], 1.0 - fraction[..., None, :]), axis=-1)
        weights = jnp.where(finite, weights + 1e-6, 0.0)
        total = jnp.sum(weights, axis=-1)
        known = inside & (total > 0)
        value = jnp.sum(weights * values, axis=-1) / jnp.maximum(total, 1e-12)
        return jnp.where(known, value, 0.0), known


def build_map_surface(tactile_map: TactileMap, settings: SurfaceSettings = SurfaceSettings(), *,
                      exclude: int | np.ndarray = -1, grid_like: MapSurface | None = None,
                      geometry: dict[str, np.ndarray] | None = None) -> MapSurface:
    """The signed-distance grid of a map's surface pixels (see the module docstring).

    Args:
        tactile_map: the map: its surface pixels (:attr:`~tactojax.mapping.TactileMap.surface_pixels`,
            drawn from the whole predicted contact mask; its contact points when it keeps none)
            and poses are read; points indented less than ``settings.min_depth_mm`` are left out.
        settings: grid pitch, reach and margin.
        exclude: an imprint left out (leave-one-out), -1 for none, or a (K,) mask of imprints
            left out (a held-out fold).
        grid_like: build on this surface's grid (origin, shape and pitch), padded to its count
            of stored blocks where it needs no more: a surface of the same map without some
            imprints then has the same shapes (no recompilation).
        geometry: the map's :meth:`~tactojax.mapping.TactileMap.host_geometry` with
            ``surface=True``, when decoded before (else decoded now).

    Returns:
        the :class:`MapSurface` (an empty map gives a one-cell grid that knows nothing).
    """
    from scipy.ndimage import binary_dilation
    from scipy.spatial import cKDTree

    geometry = tactile_map.host_geometry(surface=True) if geometry is None else geometry
    depth = -geometry["points"][..., 2]  # a sensor-frame contact point sits at z = -indentation
    valid = geometry["valid"] & (depth >= settings.min_depth_mm)
    if np.ndim(exclude) == 1:
        valid[np.asarray(exclude, bool)] = False
    elif exclude >= 0:
        valid[exclude] = False
    points = geometry["points_object"].astype(np.float64)[valid]
    normals = geometry["normals_object"].astype(np.float64)[valid]
    pitch = settings.pitch_mm
    if len(points) == 0:
        if grid_like is not None:  # its shapes, every block pointing to the unknown one
            return grid_like.replace(blocks=jnp.full_like(grid_like.blocks, jnp.nan),
                                     block_index=jnp.zeros_like(grid_like.block_index))
        return MapSurface.from_dense(np.full((2, 2, 2), np.nan), np.zeros(3), pitch)
    if grid_like is None:
        origin = points.min(axis=0) - settings.margin_mm
        shape = tuple(int(n) for n in np.ceil((points.max(axis=0) + settings.margin_mm - origin) / pitch) + 1)
    else:
        origin, shape, pitch = np.asarray(grid_like.origin, np.float64), grid_like.shape, grid_like.pitch_mm
        inside = np.all((points >= origin) & (points <= origin + (np.array(shape) - 1) * pitch), axis=1)
        points, normals = points[inside], normals[inside]
    # Only cells near a stored point can be known: mark the points' cells, grow by the reach.
    occupied = np.zeros(shape, bool)
    occupied[tuple(np.round((points - origin) / pitch).astype(int).T)] = True
    steps = int(np.ceil(settings.reach_mm / pitch))
    ball = np.linalg.norm(np.indices((2 * steps + 1,) * 3) - steps, axis=0) <= steps + 0.5
    near = np.argwhere(binary_dilation(occupied, structure=ball))
    centres = origin + near * pitch
    distance, nearest = cKDTree(points).query(centres, distance_upper_bound=settings.reach_mm, workers=-1)
    found = np.isfinite(distance)
    grid = np.full(shape, np.nan, np.float32)
    offsets = centres[found] - points[nearest[found]]
    grid[tuple(near[found].T)] = np.sum(offsets * normals[nearest[found]], axis=-1)
    surface = MapSurface.from_dense(grid, origin, pitch)
    if grid_like is not None and surface.blocks.shape[0] <= grid_like.blocks.shape[0]:
        surface = surface.padded_to(grid_like.block_index.shape, grid_like.blocks.shape[0])  # its shapes too
    return surface
