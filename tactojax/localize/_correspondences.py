"""Correspondences between query points and stored imprints, for ICP and for checks.

Projective association (the default): a point near the object's surface, expressed in the
sensor frame of a stored imprint, lies above the pixel (x / pitch, y / pitch); that imprint's
heightmap gives the touched surface there, (x, y, -h(x, y)), and its slope the surface normal.
Nothing is built at query time: a correspondence costs one 2 x 2 gather in a stored heightmap
(bilinear height, its exact slope), and the residual is a smooth function of the point inside
a pixel cell. The stored heightmaps are packed (float16, contact in the sign bit:
:func:`~tactojax.mapping.pack_heightmaps`), so a lookup is one gather of heights and contact
together. ICP, which looks up the same few candidates every iteration, first copies them into
:func:`candidate_surfaces`.

Nearest-point association (:func:`nearest_correspondences`): the classical ICP's nearest
stored contact point in 3D, brute force over the candidates' sampled points.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Bool, Float, Float16, Int

from tactojax import _struct as struct
from tactojax.localize._map import LocalizationMap
from tactojax.mapping import unpack_heightmaps


def matvec(matrix: Float[Array, "*batch 3 3"], vector: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """``matrix @ vector`` (broadcasting) written out as three products and two sums.

    On CPU this fuses with the neighbouring element-wise work, where a matrix product or a
    reduction of these small shapes would be a kernel of its own (and jaxlie's per-point
    quaternion product is dearer still).

    Raises:
        ValueError: the matrix is not 3 x 3 or the vector not of length 3 (an out-of-range
            column would otherwise be clamped silently).
    """
    if matrix.shape[-2:] != (3, 3) or vector.shape[-1] != 3:
        raise ValueError(f"matvec needs (..., 3, 3) and (..., 3), got {matrix.shape} and {vector.shape}")
    return sum(matrix[..., i] * vector[..., None, i] for i in range(3))


def valid_centroid(points: Float[Array, "P 3"], valid: Bool[Array, "P"]) -> Float[Array, "3"]:
    """Mean of the valid points (the origin when none is valid)."""
    count = jnp.maximum(jnp.sum(valid), 1)
    return jnp.sum(jnp.where(valid[:, None], points, 0.0), axis=0) / count


def transform_points(T: jaxlie.SE3, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """``T @ points`` for one transform and many points (see :func:`matvec`)."""
    return matvec(T.rotation().as_matrix(), points) + T.translation()


def surface_lookup(
    packed_heightmaps: Float16[Array, "K H W"],
    imprint: Int[Array, "*batch"],
    p_sensor: Float[Array, "*batch 3"],
    mm_per_px: float,
) -> tuple[Float[Array, "*batch"], Float[Array, "*batch 2"], Bool[Array, "*batch"]]:
    """Height and slope of stored imprints' surfaces under points, bilinearly interpolated.

    Broadcasts over leading axes (one gather for all points and imprints).

    Args:
        packed_heightmaps: (K, H, W) stored heightmaps, mm, packed with their contact masks
            (:func:`~tactojax.mapping.pack_heightmaps`).
        imprint: (...) which of the K imprints, per point.
        p_sensor: (..., 3) the points in those imprints' sensor frames, mm (x, y are read).
        mm_per_px: pixel pitch, mm.

    Returns:
        height h (mm), slope (dh/dx, dh/dy) of the bilinear interpolant, and in_contact: the
        point falls inside the image and the four surrounding pixels are in contact.
    """
    height, slope, in_contact, _ = pixel_lookup(packed_heightmaps, imprint, p_sensor, mm_per_px)
    return height, slope, in_contact


def pixel_lookup(
    packed_heightmaps: Float16[Array, "K H W"],
    imprint: Int[Array, "*batch"],
    p_sensor: Float[Array, "*batch 3"],
    mm_per_px: float,
) -> tuple[Float[Array, "*batch"], Float[Array, "*batch 2"], Bool[Array, "*batch"], Bool[Array, "*batch"]]:
    """:func:`surface_lookup`, also returning ``inside`` (the point falls inside the image)."""
    count, height_px, width_px = packed_heightmaps.shape
    col = p_sensor[..., 0] / mm_per_px + (width_px - 1) / 2.0
    row = p_sensor[..., 1] / mm_per_px + (height_px - 1) / 2.0
    inside = (col >= 0) & (col <= width_px - 1) & (row >= 0) & (row <= height_px - 1)
    col = jnp.clip(col, 0.0, width_px - 1.0)
    row = jnp.clip(row, 0.0, height_px - 1.0)
    col0 = jax.lax.stop_gradient(jnp.clip(jnp.floor(col), 0, width_px - 2))
    row0 = jax.lax.stop_gradient(jnp.clip(jnp.floor(row), 0, height_px - 2))
    fc, fr = col - col0, row - row0
    cell = (imprint, row0.astype(jnp.int32), col0.astype(jnp.int32))
    h, contact = unpack_heightmaps(_cells(packed_heightmaps, *cell))
    contact = jnp.all(contact, axis=(-2, -1))
    h00, h01, h10, h11 = h[..., 0, 0], h[..., 0, 1], h[..., 1, 0], h[..., 1, 1]
    top = h00 + (h01 - h00) * fc
    bottom = h10 + (h11 - h10) * fc
    value = top + (bottom - top) * fr
    slope_x = ((h01 - h00) * (1 - fr) + (h11 - h10) * fr) / mm_per_px
    slope_y = (bottom - top) / mm_per_px
    return value, jnp.stack([slope_x, slope_y], axis=-1), inside & contact, inside


def _cells(
    images: Array, imprint: Int[Array, "*batch"], row: Int[Array, "*batch"], col: Int[Array, "*batch"]
) -> Array:
    """The 2 x 2 pixel cells ``images[imprint, row:row + 2, col:col + 2]``, shape (..., 2, 2).

    One gather of 2 x 2 windows from the (K * H, W) stacked rows: cheaper on CPU than four
    gathers of single pixels. ``row`` must lie in [0, H - 2] and ``col`` in [0, W - 2]; the
    imprint index is clipped to [0, K - 1], so every window is in bounds.
    """
    count, height_px, width_px = images.shape
    corner = jnp.stack([jnp.clip(imprint, 0, count - 1) * height_px + row, col], axis=-1)
    dimensions = jax.lax.GatherDimensionNumbers(offset_dims=(corner.ndim - 1, corner.ndim),
                                                collapsed_slice_dims=(), start_index_map=(0, 1))
    return jax.lax.gather(images.reshape(count * height_px, width_px), corner, dimensions, (2, 2),
                          mode="promise_in_bounds")


def _normal_from_slope(slope: Float[Array, "*batch 2"]) -> Float[Array, "*batch 3"]:
    """Unit normal (pointing out of the object, towards -z) of the surface z = -h."""
    normal = jnp.concatenate([-slope, -jnp.ones_like(slope[..., :1])], axis=-1)
    return normal / jnp.linalg.norm(normal, axis=-1, keepdims=True)


@struct.dataclass
class Correspondences:
    """For every query point, its best match among N candidate imprints (fixed shapes)."""

    candidate: Int[Array, "P"]
    """Which of the N candidates matched (the nearest one where none did)."""
    residual: Float[Array, "P"]
    """Point-to-plane residual, mm."""
    target: Float[Array, "P 3"]
    """Matched surface point, object frame, mm."""
    normal: Float[Array, "P 3"]
    """Unit surface normal there, object frame."""
    valid: Bool[Array, "P"]
    """A match exists: in contact in some candidate and within the maximum distance."""


def candidate_poses(view: LocalizationMap, candidates: Int[Array, "*batch"]) -> jaxlie.SE3:
    """(*batch,) object -> sensor transforms of the candidate imprints."""
    return jax.tree.map(lambda x: x[candidates], view.T_object_sensor).inverse()


def candidate_surfaces(view: LocalizationMap, candidates: Int[Array, "N"]) -> Float16[Array, "N H W"]:
    """The candidates' packed heightmaps: a small array to look up."""
    return view.packed_heightmaps[candidates]


def find_correspondences(
    view: LocalizationMap,
    candidates: Int[Array, "N"] | Int[Array, "P N"],
    candidate_valid: Bool[Array, "N"] | Bool[Array, "P N"],
    points_object: Float[Array, "P 3"],
    points_valid: Bool[Array, "P"],
    max_distance_mm: float,
    *,
    T_sensor_candidate: jaxlie.SE3 | None = None,
    surfaces: Float16[Array, "N H W"] | None = None,
    blocks: int = 1,
    active_blocks: Int[Array, ""] | None = None,
) -> Correspondences:
    """Match every point to the candidate imprint whose surface is nearest (point-to-plane).

    Each point is projected into each of its candidates' heightmaps; among the candidates where
    it falls in contact with ``|residual| <= max_distance_mm``, the one with the smallest
    ``|residual|`` wins.

    Args:
        view: the map.
        candidates: (N,) imprint indices every point may match (e.g. the N most similar to the
            query), or (P, N): each point its own (e.g. the points of several touches, each
            against the imprints around where it lands).
        candidate_valid: which candidates are real, shaped as ``candidates``.
        points_object: (P, 3) query points placed in the object frame, mm.
        points_valid: (P,) which query points are real.
        max_distance_mm: correspondences farther than this are rejected, mm.
        T_sensor_candidate: :func:`candidate_poses` of ``candidates``, if already computed.
        surfaces: :func:`candidate_surfaces` of (N,) shared candidates, if already computed
            (cheaper lookups; without them the points are looked up in the map's own
            heightmaps).
        blocks, active_blocks: the points come in ``blocks`` equal blocks (static; e.g. the
            touches a belief holds), of which only the first ``active_blocks`` (traced) can hold
            valid points: only those are looked up, the others left unmatched (per-point
            candidates only; None: every block).

    Returns:
        :class:`Correspondences` of the P points (``candidate`` indexes the point's N candidates).
    """
    per_point = candidates.ndim == 2
    if T_sensor_candidate is None:
        T_sensor_candidate = candidate_poses(view, candidates)
    if surfaces is not None and per_point:
        raise ValueError("surfaces are for candidates shared by all points, not per-point candidates")
    if active_blocks is not None:
        if not per_point or points_object.shape[0] % blocks:
            raise ValueError(f"blocks need per-point candidates and {points_object.shape[0]} points in {blocks} "
                             "equal blocks")
        size = points_object.shape[0] // blocks

        def block(b, found):
            part = lambda x: jax.lax.dynamic_slice_in_dim(x, b * size, size)  # noqa: E731
            matches = find_correspondences(view, part(candidates), part(candidate_valid), part(points_object),
                                           part(points_valid), max_distance_mm,
                                           T_sensor_candidate=jax.tree.map(part, T_sensor_candidate))
            return jax.tree.map(lambda whole, new: jax.lax.dynamic_update_slice_in_dim(whole, new, b * size, 0),
                                found, matches)

        count = points_object.shape[0]
        unmatched = Correspondences(candidate=jnp.zeros(count, jnp.int32), residual=jnp.zeros(count),
                                    target=jnp.zeros((count, 3)), normal=jnp.zeros((count, 3)),
                                    valid=jnp.zeros(count, bool))
        return jax.lax.fori_loop(0, active_blocks, block, unmatched)
    # (P, N) sensor-frame points: rotate and translate with explicit matrices.
    rotation = T_sensor_candidate.rotation().as_matrix()  # (N, 3, 3) or (P, N, 3, 3)
    translation = T_sensor_candidate.translation()
    p_sensor = matvec(rotation, points_object[:, None]) + translation
    if surfaces is None:
        surfaces, imprint = view.packed_heightmaps, candidates
    else:
        imprint = jnp.arange(candidates.shape[0])
    imprint = jnp.broadcast_to(imprint, p_sensor.shape[:2])
    height, slope, in_contact = surface_lookup(surfaces, imprint, p_sensor, view.mm_per_px)
    residual = (p_sensor[..., 2] + height) * -jax.lax.rsqrt(1.0 + jnp.sum(slope**2, axis=-1))
    ok = (in_contact & jnp.broadcast_to(candidate_valid, in_contact.shape) & points_valid[:, None]
          & (jnp.abs(residual) <= max_distance_mm))
    best = jnp.argmin(jnp.where(ok, jnp.abs(residual), jnp.inf), axis=1)
    take = lambda x: jnp.take_along_axis(x, best.reshape(-1, *[1] * (x.ndim - 1)), axis=1)[:, 0]  # noqa: E731
    p_best, slope_best = take(p_sensor), take(slope)
    height_best = take(height)
    normal = _normal_from_slope(slope_best)
    target = jnp.concatenate([p_best[:, :2], -height_best[:, None]], axis=-1)
    # Back to the object frame: R^T (x - t).
    if per_point:
        rotation_best, translation_best = take(rotation), take(translation)
    else:
        rotation_best, translation_best = rotation[best], translation[best]
    inverse_best = jnp.swapaxes(rotation_best, -1, -2)
    target_object = matvec(inverse_best, target - translation_best)
    normal_object = matvec(inverse_best, normal)
    return Correspondences(candidate=best, residual=take(residual),
                           target=target_object, normal=normal_object, valid=jnp.any(ok, axis=1))


def nearest_correspondences(
    view: LocalizationMap,
    candidates: Int[Array, "N"],
    candidate_valid: Bool[Array, "N"],
    points_object: Float[Array, "P 3"],
    points_valid: Bool[Array, "P"],
    max_distance_mm: float,
) -> Correspondences:
    """Match every point to the nearest stored contact point of the candidates (3D, brute force).

    The classical ICP association (the paper's): its basin is wider than the projection's (a
    point finds a match however far the candidates' contact lies, within ``max_distance_mm``),
    at the price of the map's point sampling (``LocalizationMap.points``). The residual is
    point-to-plane with the stored normal.

    Args:
        view: the map.
        candidates: (N,) imprint indices; candidate_valid (N,).
        points_object: (P, 3) query points in the object frame, mm; points_valid (P,).
        max_distance_mm: matches farther (Euclidean) than this are rejected, mm.

    Returns:
        :class:`Correspondences` (``candidate``: which of the N imprints the match belongs to).
    """
    targets = view.points[candidates].reshape(-1, 3)  # (N * Q, 3)
    normals = view.normals[candidates].reshape(-1, 3)
    target_valid = (view.points_valid[candidates] & candidate_valid[:, None]).reshape(-1)
    squared = (jnp.sum(points_object**2, axis=-1)[:, None] - 2.0 * points_object @ targets.T
               + jnp.sum(targets**2, axis=-1)[None, :])
    squared = jnp.where(target_valid[None, :], squared, jnp.inf)
    nearest = jnp.argmin(squared, axis=1)
    distance_ok = jnp.take_along_axis(squared, nearest[:, None], axis=1)[:, 0] <= max_distance_mm**2
    target, normal = targets[nearest], normals[nearest]
    residual = jnp.sum(normal * (points_object - target), axis=-1)
    return Correspondences(candidate=nearest // view.points.shape[1], residual=residual, target=target,
                           normal=normal, valid=points_valid & distance_ok & target_valid[nearest])
