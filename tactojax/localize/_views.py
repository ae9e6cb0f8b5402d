"""The map's surface as seen from each stored imprint: one local view per imprint, built once.

A pose hypothesis for a new touch lies near some stored imprint ``k``. To score it, the touch
is compared with the object's surface around ``k``, as the sensor would see it from there:
what the map says is at each (x, y) of ``k``'s sensor plane, beyond the image's borders too,
because a hypothesis may be shifted a few millimetres from ``k``. :func:`build_surface_views`
resamples, on a grid in each imprint's sensor frame that extends its image by a margin, the
predicted surfaces of its spatial neighbours that face the same way (their contact centres
nearest, their gel normals within 60 degrees of its own):

- ``surface_z``: the surface's z in the view's frame (mm; NaN where no neighbour felt it),
  the mean over the neighbours that felt it there;
- ``free_z``: where a neighbour's gel was there and felt *nothing*, the object does not reach
  into that gel: nothing of the object lies at z < ``free_z`` along that column (mm; -inf
  where no neighbour says so). This is the map's negative information.

A neighbour's heightmap is read along the view's columns by one fixed-point step: the column
(x, y) is placed at the view's gel plane, looked up in the neighbour's heightmap, and the
surface point found there is moved back to the column along the neighbour's local tangent
plane (exact for planar patches, second order in the angle between the two views otherwise).
Every view has the same fixed shape, so building and reading views jits once per map size.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
from flax import struct
from jaxtyping import Array, Bool, Float, Int

from tactojax.localize._consistency import FREE_HEIGHT_MM
from tactojax.localize._correspondences import _cells, candidate_poses, matvec, pixel_lookup
from tactojax.localize._map import LocalizationMap

@dataclass(frozen=True)
class ViewSettings:
    """How local views are built (static)."""

    pitch_mm: float = 0.5
    """Grid step of a view, mm."""
    margin_mm: float = 6.0
    """How far a view extends beyond its imprint's image on every side, mm."""
    neighbours: int = 8
    """Imprints (the view's own first) resampled into each view."""
    min_facing_cosine: float = 0.5
    """A neighbour's gel normal must be within acos(this) of the view's (60 degrees)."""

    def grid_shape(self, image_shape: tuple[int, int], mm_per_px: float) -> tuple[int, int]:
        """(rows, columns) of a view for images of ``image_shape`` pixels."""
        height_mm, width_mm = ((n - 1) * mm_per_px for n in image_shape)
        return (int(round((height_mm + 2 * self.margin_mm) / self.pitch_mm)) + 1,
                int(round((width_mm + 2 * self.margin_mm) / self.pitch_mm)) + 1)


@struct.dataclass
class SurfaceViews:
    """K local views of the map's surface, one per stored imprint (see the module docstring)."""

    surface_z: Float[Array, "K R C"]
    """Surface z in each imprint's sensor frame, mm; NaN where unknown."""
    free_z: Float[Array, "K R C"]
    """Nothing of the object lies at z < free_z there (sensor frame, mm); -inf where unknown."""
    neighbours: Int[Array, "K N"]
    """The imprints resampled into each view (the view's own first)."""
    neighbours_valid: Bool[Array, "K N"]
    """Which of them are real (available and facing the same way)."""
    pitch_mm: float = struct.field(pytree_node=False)
    """Grid step, mm; cell (r, c) is at x = (c - (C - 1) / 2) pitch, y = (r - (R - 1) / 2) pitch."""

    def lookup(
        self, view: Int[Array, "*batch"], p_view: Float[Array, "*batch 3"]
    ) -> tuple[Float[Array, "*batch"], Bool[Array, "*batch"], Float[Array, "*batch"]]:
        """Surface z (bilinear over the known corners of its cell), whether it is known (any
        corner), and free_z (the largest of the four corners) under points ``p_view`` in the
        frames of views ``view``."""
        count, rows, cols = self.surface_z.shape
        col = p_view[..., 0] / self.pitch_mm + (cols - 1) / 2.0
        row = p_view[..., 1] / self.pitch_mm + (rows - 1) / 2.0
        inside = (col >= 0) & (col <= cols - 1) & (row >= 0) & (row <= rows - 1)
        col0 = jnp.clip(jnp.floor(col), 0, cols - 2)
        row0 = jnp.clip(jnp.floor(row), 0, rows - 2)
        fc, fr = jnp.clip(col - col0, 0.0, 1.0), jnp.clip(row - row0, 0.0, 1.0)
        index = (view, row0.astype(jnp.int32), col0.astype(jnp.int32))
        z = _cells(self.surface_z, *index)
        # Bilinear over the known corners (weights renormalised): a thin contact strip, narrower
        # than a cell, stays known.
        weight = jnp.stack([jnp.stack([(1 - fr) * (1 - fc), (1 - fr) * fc], -1),
                            jnp.stack([fr * (1 - fc), fr * fc], -1)], -2) + 1e-6
        weight = jnp.where(jnp.isfinite(z), weight, 0.0)
        total = jnp.sum(weight, axis=(-2, -1))
        known = inside & (total > 0)
        value = jnp.sum(weight * jnp.where(jnp.isfinite(z), z, 0.0), axis=(-2, -1)) / jnp.maximum(total, 1e-12)
        free = jnp.where(inside, jnp.max(_cells(self.free_z, *index), axis=(-2, -1)), -jnp.inf)
        return value, known, free


def facing_neighbours(
    view: LocalizationMap, n: int, available: Bool[Array, "K"], min_facing_cosine: float
) -> tuple[Int[Array, "K n"], Bool[Array, "K n"]]:
    """For every imprint, the n available imprints facing the same way whose contact centres are nearest.

    The imprint itself comes first when available (distance 0).
    """
    normals = view.T_object_sensor.rotation().as_matrix()[..., :, 2]  # (K, 3) gel normals
    facing = normals @ normals.T >= min_facing_cosine
    distance = jnp.linalg.norm(view.centres[:, None] - view.centres[None], axis=-1)
    ok = facing & available[None, :]
    _, nearest = jax.lax.top_k(jnp.where(ok, -distance, -jnp.inf), n)
    return nearest, jnp.take_along_axis(ok, nearest, axis=1) & available[:, None]


def _plane_z(point: Float[Array, "*b 3"], normal: Float[Array, "*b 3"], xy: Float[Array, "*b 2"]) -> Float[Array, "*b"]:
    """z at ``xy`` of the plane through ``point`` with ``normal`` (normal z kept away from 0)."""
    nz = jnp.where(jnp.abs(normal[..., 2]) < 0.2, 0.2 * jnp.sign(normal[..., 2] + 1e-12), normal[..., 2])
    return point[..., 2] - jnp.sum(normal[..., :2] * (xy - point[..., :2]), axis=-1) / nz


def _one_view(view: LocalizationMap, surfaces, index, neighbours, neighbours_valid, grid_xy):
    """surface_z and free_z of view ``index`` on ``grid_xy`` (R, C, 2)."""
    T_view = jax.tree.map(lambda x: x[index], view.T_object_sensor)
    T_neighbour_view = candidate_poses(view, neighbours) @ T_view  # (N,) view frame -> neighbour frame
    rotation = T_neighbour_view.rotation().as_matrix()  # (N, 3, 3)
    translation = T_neighbour_view.translation()
    rotation_back = jnp.swapaxes(rotation, -1, -2)  # neighbour -> view
    columns = jnp.concatenate([grid_xy, jnp.zeros((*grid_xy.shape[:-1], 1))], axis=-1)  # (R, C, 3) on the gel plane
    p = matvec(rotation[:, None, None], columns[None]) + translation[:, None, None]  # (N, R, C, 3)
    imprint = jnp.broadcast_to(jnp.arange(neighbours.shape[0])[:, None, None], p.shape[:-1])
    height, slope, in_contact, inside = pixel_lookup(surfaces, None, imprint, p, view.mm_per_px)
    on_surface = jnp.stack([p[..., 0], p[..., 1], -height], axis=-1)
    tangent_normal = jnp.stack([slope[..., 0], slope[..., 1], jnp.ones_like(height)], axis=-1)  # of z = -h
    back = lambda v: matvec(rotation_back[:, None, None], v)  # noqa: E731
    surface_point = back(on_surface - translation[:, None, None])
    z = _plane_z(surface_point, back(tangent_normal), grid_xy[None])
    felt = in_contact & neighbours_valid[:, None, None]
    count = jnp.sum(felt, axis=0)
    surface_z = jnp.where(count > 0, jnp.sum(jnp.where(felt, z, 0.0), axis=0) / jnp.maximum(count, 1), jnp.nan)
    # Free gel: inside the neighbour's image, not in contact, barely indented (NaN-free heights
    # come from the raw heightmap, where the contact surfaces hold NaN).
    raw_height, _, _, _ = pixel_lookup(view.heightmaps, None, neighbours[imprint], p, view.mm_per_px)
    free = inside & ~in_contact & (raw_height < FREE_HEIGHT_MM) & neighbours_valid[:, None, None]
    gel_point = back(jnp.concatenate([p[..., :2], jnp.zeros_like(p[..., :1])], axis=-1) - translation[:, None, None])
    gel_normal = jnp.broadcast_to(rotation_back[:, None, None, :, 2], p.shape)
    free_z = jnp.max(jnp.where(free, _plane_z(gel_point, gel_normal, grid_xy[None]), -jnp.inf), axis=0)
    return surface_z, free_z


def build_surface_views(
    view: LocalizationMap,
    settings: ViewSettings = ViewSettings(),
    *,
    indices: Int[Array, "V"] | None = None,
    exclude: int | Int[Array, ""] = -1,
) -> SurfaceViews:
    """Local views of the map's surface around stored imprints (see the module docstring).

    Args:
        view: the map.
        settings: grid and neighbour settings (static).
        indices: (V,) which imprints' views to build (default: all K; the result then has V rows).
        exclude: an imprint never resampled (leave-one-out), -1 for none.

    Returns:
        :class:`SurfaceViews` with one view per index.
    """
    count = len(view)
    available = view.imprint_valid & (jnp.arange(count) != exclude)
    neighbours, neighbours_valid = facing_neighbours(view, settings.neighbours, available,
                                                     settings.min_facing_cosine)
    if indices is None:
        indices = jnp.arange(count)
    neighbours, neighbours_valid = neighbours[indices], neighbours_valid[indices]
    rows, cols = settings.grid_shape(view.heightmaps.shape[1:], view.mm_per_px)
    x = (jnp.arange(cols) - (cols - 1) / 2.0) * settings.pitch_mm
    y = (jnp.arange(rows) - (rows - 1) / 2.0) * settings.pitch_mm
    grid_xy = jnp.stack(jnp.meshgrid(x, y, indexing="xy"), axis=-1)
    surfaces = jnp.where(view.masks, view.heightmaps, jnp.nan)

    def one(args):
        index, nbrs, nbrs_valid = args
        return _one_view(view, surfaces[nbrs], index, nbrs, nbrs_valid, grid_xy)

    surface_z, free_z = jax.lax.map(one, (indices, neighbours, neighbours_valid), batch_size=16)
    return SurfaceViews(surface_z=surface_z, free_z=free_z, neighbours=neighbours,
                        neighbours_valid=neighbours_valid, pitch_mm=settings.pitch_mm)
