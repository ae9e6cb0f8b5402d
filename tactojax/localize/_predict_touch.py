"""What a grasp would feel at a pose hypothesis, from the map's surface alone (active touch).

A parallel-jaw grasp (``tactojax.simulate``'s grasp model, replayed on the *map*): the gripper
is commanded to ``T_world_gripper`` fully open; each gel's pixel rays are cast along its +z
against the map's signed-distance surface (:class:`~tactojax.localize.MapSurface`) with the
object at ``T_world_object``; each jaw travels to its first contact and presses on by
``depth_mm``; the rigid indentation ``travel - distance`` is the predicted heightmap and its
positive part the contact mask. The simulator's mesh is never read: this is what the belief's
likelihood would see, so the next-grasp choice (:func:`~tactojax.localize.active.next_grasp`) can
score a predicted touch with the same likelihood.

Rays are sphere traced through a :class:`MarchingGrid`: the surface's signed distance where the
map knows it, and elsewhere the distance to the nearest cell where it does (a lower bound on the
distance to the surface, so no step jumps across it). A ray hits where the known distance turns
negative; the hit is placed by linear interpolation of the trilinear distances on both sides.
Gaps in the map (surface never touched) let rays through: the map predicts no contact there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from tactojax import _struct as struct
from tactojax.geometry import opposite_sensor_pose, pixel_grid, sensor_pose
from tactojax.localize._correspondences import matvec
from tactojax.localize._points import TouchEvidence, draw_pixels, pixel_priority
from tactojax.localize._surface import MapSurface, row_major_strides


@struct.dataclass
class MarchingGrid:
    """A grid that sphere tracing can step through: the map surface's signed distance where it
    is known, and the (positive) distance to the nearest known cell elsewhere, mm."""

    distance: Float[Array, "X Y Z"] | Float[Array, "L"]
    """Signed distance where known, else the distance to the nearest known cell (both mm); flat
    where ``shape`` is given."""
    known: Bool[Array, "X Y Z"] | Bool[Array, "L"]
    """Where the map knows the surface's signed distance."""
    origin: Float[Array, "3"]
    """Object-frame position of cell (0, 0, 0), mm."""
    pitch_mm: float = struct.field(pytree_node=False)
    """Grid step, mm."""
    cells: Int[Array, "3"] | None = None
    """Cells along each axis when they are data: the grid is then the ``prod(cells)`` values of
    the flat ``distance`` and ``known`` from ``offset`` on (one map's grid among a catalog's,
    :class:`StackedMarchingGrids`; None: the arrays are the grid itself)."""
    offset: Int[Array, ""] | None = None
    """Where the grid starts in the flat arrays (with ``cells``)."""


@struct.dataclass
class StackedMarchingGrids:
    """The marching grids of several maps in one structure: each flattened, one after the other.
    :meth:`grid` gives map ``m``'s as a :class:`MarchingGrid` over the shared arrays (nothing
    copied, the same shapes for every map: one compiled program reads any of them), where grids
    padded to the largest would take the largest grid's cells per map (31 GB for the 79 maps of
    ``map-catalog ... ycb:all``, against 2.2 GB for their own grids)."""

    distance: Float[Array, "L"]
    """Every grid's :attr:`MarchingGrid.distance`, flat, one after the other, mm."""
    known: Bool[Array, "L"]
    """Every grid's :attr:`MarchingGrid.known`, flat."""
    offsets: Int[Array, "M"]
    """Where each grid starts."""
    cells: Int[Array, "M 3"]
    """Cells along each axis of each grid."""
    origins: Float[Array, "M 3"]
    """Object-frame position of each grid's cell (0, 0, 0), mm."""
    pitch_mm: float = struct.field(pytree_node=False)
    """Grid step, mm."""

    @staticmethod
    def from_grids(grids) -> StackedMarchingGrids:
        """The grids (host; all of one pitch) in one structure."""
        grids = list(grids)
        if len({g.pitch_mm for g in grids}) != 1 or any(g.cells is not None for g in grids):
            raise ValueError("stacked marching grids need grids of their own, all of one pitch")
        sizes = np.array([np.size(g.distance) for g in grids])
        if sizes.sum() >= 2**31:  # read through int32 indices
            raise ValueError(f"the marching grids hold {sizes.sum():,} cells: more than one stack can index (2**31)")
        return StackedMarchingGrids(
            distance=jnp.asarray(np.concatenate([np.asarray(g.distance, np.float32).ravel() for g in grids])),
            known=jnp.asarray(np.concatenate([np.asarray(g.known).ravel() for g in grids])),
            offsets=jnp.asarray(np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int32)),
            cells=jnp.asarray(np.array([np.shape(g.distance) for g in grids], np.int32)),
            origins=jnp.asarray(np.stack([np.asarray(g.origin, np.float32) for g in grids])),
            pitch_mm=grids[0].pitch_mm)

    def grid(self, index: int | Int[Array, ""]) -> MarchingGrid:
        """Map ``index``'s grid (jit-compatible; ``index`` may be traced)."""
        return MarchingGrid(distance=self.distance, known=self.known, origin=self.origins[index],
                            pitch_mm=self.pitch_mm, cells=self.cells[index], offset=self.offsets[index])


def map_marching_grid(view, *, min_points: int = 4) -> MarchingGrid:
    """The :class:`MarchingGrid` of a :class:`~tactojax.localize.LocalizationMap`, its stray
    points filtered out (:func:`marching_grid` with the map's contact points)."""
    points = np.asarray(view.points)[np.asarray(view.points_valid) & np.asarray(view.imprint_valid)[:, None]]
    return marching_grid(view.surface, points, min_points=min_points)


def marching_grid(surface: MapSurface, points: Float[Array, "N 3"] | None = None, *, min_points: int = 0,
                  radius_mm: float = 1.5) -> MarchingGrid:
    """The :class:`MarchingGrid` of a map's surface (host, SciPy's Euclidean distance transform;
    well under a second for the catalog maps).

    Args:
        surface: the map's surface.
        points: (N, 3) the map's contact points, object frame, mm (only with ``min_points``).
        min_points: a cell counts as known only where at least this many of ``points`` lie
            within ``radius_mm`` (stray points, e.g. at the rims of a face, then stop no ray).
        radius_mm: the neighbourhood of that count, mm.
    """
    from scipy.ndimage import distance_transform_edt
    from scipy.spatial import cKDTree

    distance = np.asarray(surface.distance, np.float32)
    known = np.isfinite(distance)
    if min_points > 0 and points is not None and known.any():
        # The points' cells within a ball of ``steps + 0.5`` cells, counted at the known cells
        # only (a k-d tree over the points' cells: a tenth of the time of a dense convolution).
        cells = np.round((np.asarray(points, np.float64).reshape(-1, 3) - np.asarray(surface.origin))
                         / surface.pitch_mm).astype(int)
        inside = np.all((cells >= 0) & (cells < np.array(distance.shape)), axis=1)
        steps = int(np.ceil(radius_mm / surface.pitch_mm))
        where = np.argwhere(known)
        counts = (cKDTree(cells[inside]).query_ball_point(where, steps + 0.5, return_length=True, workers=-1)
                  if inside.any() else np.zeros(len(where), int))
        known[tuple(where[counts < min_points].T)] = False
    if not known.any():
        far = np.full(distance.shape, 1e3, np.float32)
        return MarchingGrid(distance=jnp.asarray(far), known=jnp.asarray(known), origin=surface.origin,
                            pitch_mm=surface.pitch_mm)
    to_known = distance_transform_edt(~known).astype(np.float32) * surface.pitch_mm
    return MarchingGrid(distance=jnp.asarray(np.where(known, distance, to_known)), known=jnp.asarray(known),
                        origin=surface.origin, pitch_mm=surface.pitch_mm)


@dataclass(frozen=True)
class PredictionSettings:
    """How a touch is predicted (static)."""

    rows: int = 8
    """Ray rows across the gel (image rows, spread evenly over its height)."""
    cols: int = 12
    """Ray columns across the gel."""
    steps: int = 32
    """Sphere-tracing steps per ray (a ray that has not hit by then misses)."""
    min_step_mm: float = 0.2
    """Shortest step, mm (the largest overshoot before the hit is interpolated back)."""
    depth_mm: float = 1.0
    """How far each gel presses on past its first contact, mm (the simulator's default)."""
    max_opening_mm: float = 110.0
    """The open gripper's opening: where each jaw starts, mm."""
    gel_thickness_mm: float = 2.0
    """A grasp that would indent a gel deeper than this is not made, mm."""
    min_indentation_mm: float = 1e-3
    """Indentation that counts as contact, mm."""
    free_clearance_mm: float = 1.0
    """Where the map knows no surface, a gel point this far from it counts as free, mm."""


@struct.dataclass
class PredictedGrasp:
    """What a grasp would feel, per finger (F = 1: the sensor jaw; 2: both jaws), on a coarse
    ray grid of the gel (R rows x C columns)."""

    heightmap: Float[Array, "F R C"]
    """Rigid indentation of each gel at the ray grid, mm (>= 0)."""
    mask: Bool[Array, "F R C"]
    """Predicted contact."""
    free: Bool[Array, "F R C"]
    """Predicted no contact where the map is sure of it: the closed gel plane lies outside the
    surface (known distance > 0), or more than ``free_clearance_mm`` from where the map knows it
    (a ray through a gap in the map, e.g. a face never touched, is neither contact nor free)."""
    T_world_sensor: jaxlie.SE3
    """(F,) each gel's pose once the jaws closed, mm."""
    opening: Float[Array, ""]
    """Predicted gripper opening, mm."""
    valid: Bool[Array, ""]
    """Whether the jaws close on the object within the opening (both touch, neither starts
    inside it, no gel indented past its thickness)."""
    clearance_mm: Float[Array, ""]
    """How far the open jaws start from the object along the closing axis, the nearer of the
    two, mm (0 where one starts inside it, as far as the map knows: within its surface's known
    band; the opening where neither would touch it)."""


def _read(grid: MarchingGrid, points: Float[Array, "N 3"]) -> tuple[Float[Array, "N"], Bool[Array, "N"]]:
    """The marching grid's nearest cell at object-frame points: its value (mm; outside the grid,
    the distance to the grid's box) and whether the surface is known there."""
    # The grid's own arrays: static; one grid of a stack's flat arrays: the same arithmetic, traced.
    shape, start = (np.array(grid.distance.shape), 0) if grid.cells is None else (grid.cells, grid.offset)
    strides = row_major_strides(shape)
    cell = (points - grid.origin) / grid.pitch_mm
    inside = jnp.all((cell >= 0) & (cell <= shape - 1), axis=-1)
    index = start + jnp.clip(jnp.round(cell), 0, shape - 1).astype(jnp.int32) @ strides
    value, known = grid.distance.reshape(-1)[index], grid.known.reshape(-1)[index] & inside
    outside = jnp.linalg.norm(jnp.maximum(jnp.maximum(-cell, cell - (shape - 1)), 0.0), axis=-1) * grid.pitch_mm
    return jnp.where(inside, value, outside + grid.pitch_mm), known


def _march(grid: MarchingGrid, surface: MapSurface, origins: Float[Array, "N 3"], direction: Float[Array, "3"],
           settings: PredictionSettings) -> tuple[Float[Array, "N"], Bool[Array, "N"], Bool[Array, "N"]]:
    """Distance along ``direction`` from every origin to the map's surface (object frame, mm),
    whether each ray hit it within the open gripper's travel, and whether it started inside."""
    slack = grid.pitch_mm * math.sqrt(3.0) / 2.0  # the nearest cell's value is off by at most this

    def read(t):
        return _read(grid, origins + t[:, None] * direction)

    def step(_, carry):
        t, previous, hit = carry
        value, known = read(t)
        crossed = ~hit & known & (value <= 0.0)
        size = jnp.where(known, jnp.maximum(value, settings.min_step_mm),
                         jnp.maximum(value - slack, settings.min_step_mm))
        moving = ~hit & ~crossed
        return (jnp.where(moving, t + size, t), jnp.where(moving, t, previous), hit | crossed)

    zero = jnp.zeros(origins.shape[0])
    start_value, start_known = read(zero)
    starts_inside = start_known & (start_value < -slack)
    t, previous, hit = jax.lax.fori_loop(0, settings.steps, step, (zero, zero, jnp.zeros(origins.shape[0], bool)))
    # Place the hit between the last point outside and the first inside (trilinear distances).
    before, _ = surface.signed_distance(origins + previous[:, None] * direction)
    after, _ = surface.signed_distance(origins + t[:, None] * direction)
    fraction = jnp.clip(before / jnp.maximum(before - after, 1e-6), 0.0, 1.0)
    distance = previous + fraction * (t - previous)
    hit = hit & (distance <= settings.max_opening_mm)
    return distance, hit, starts_inside


def ray_grid(height_mm: float, width_mm: float, settings: PredictionSettings) -> Float[Array, "R C 2"]:
    """Sensor-frame (x, y) of the prediction's rays: a ``rows x cols`` grid of pixel centres
    spread evenly over a gel of ``height_mm x width_mm``, mm."""
    return pixel_grid(settings.rows, settings.cols, 1.0) * jnp.array(
        [width_mm / settings.cols, height_mm / settings.rows])


def predict_grasp(
    grid: MarchingGrid,
    surface: MapSurface,
    T_world_object: jaxlie.SE3,
    T_world_gripper: jaxlie.SE3,
    gel_size_mm: tuple[float, float],
    settings: PredictionSettings = PredictionSettings(),
    *,
    fingers: int = 2,
) -> PredictedGrasp:
    """The touch(es) a grasp would give with the object at ``T_world_object``, from the map.

    Args:
        grid: the map's :class:`MarchingGrid` (:func:`marching_grid`).
        surface: the map's surface (the hits' trilinear refinement).
        T_world_object: the pose hypothesis, mm.
        T_world_gripper: the commanded gripper pose, fully open, mm.
        gel_size_mm: (height, width) of the gel, mm (static).
        settings: ray grid, contact depth, gripper (static).
        fingers: 2: both jaws carry a gel; 1: the opposite jaw is a rigid pad (it stops at
            first contact and reports no touch) (static).

    Returns:
        the :class:`PredictedGrasp`. Pure; vmap over hypotheses and grasps.
    """
    opening = jnp.float32(settings.max_opening_mm)
    T_object_world = T_world_object.inverse()
    xy = ray_grid(*gel_size_mm, settings).reshape(-1, 2)
    travels, heightmaps, free, touched, collides, clearances = [], [], [], [], [], []
    for pose in (sensor_pose, opposite_sensor_pose):
        T_object_start = T_object_world @ pose(T_world_gripper, opening)
        rotation = T_object_start.rotation().as_matrix()
        origins = matvec(rotation, jnp.concatenate([xy, jnp.zeros_like(xy[:, :1])], axis=-1)) + T_object_start.translation()
        distance, hit, inside = _march(grid, surface, origins, rotation[:, 2], settings)
        any_hit = jnp.any(hit)
        first = jnp.where(any_hit, jnp.min(jnp.where(hit, distance, jnp.inf)), 0.0)
        travel = first + (settings.depth_mm if len(travels) < fingers else 0.0)
        heightmaps.append(jnp.where(hit, jnp.maximum(travel - distance, 0.0), 0.0).reshape(settings.rows,
                                                                                            settings.cols))
        closed = origins + travel * rotation[:, 2]  # the closed gel plane
        clearance, _ = _read(grid, closed)
        value, known = surface.signed_distance(closed, interpolate=False)  # as the likelihood reads it
        free.append(((known & (value > 0.0)) | (~known & (clearance > settings.free_clearance_mm))).reshape(
            settings.rows, settings.cols))
        travels.append(travel)
        touched.append(any_hit)
        collides.append(jnp.any(inside))
        clearances.append(jnp.where(jnp.any(inside), 0.0, jnp.where(any_hit, first, opening)))
    final_opening = opening - travels[0] - travels[1]
    finger_poses = [sensor_pose, opposite_sensor_pose][:fingers]
    T_world_sensor = jax.tree.map(
        lambda *x: jnp.stack(x),
        *(pose(T_world_gripper, opening) @ jaxlie.SE3.from_translation(jnp.array([0.0, 0.0, 1.0]) * travel)
          for pose, travel in zip(finger_poses, travels)))
    heightmap = jnp.stack(heightmaps[:fingers])
    valid = (touched[0] & touched[1] & ~collides[0] & ~collides[1] & (final_opening > 0)
             & (jnp.max(heightmap) < settings.gel_thickness_mm))
    mask = heightmap > settings.min_indentation_mm
    return PredictedGrasp(heightmap=heightmap, mask=mask, free=~mask & jnp.stack(free[:fingers]),
                          T_world_sensor=T_world_sensor, opening=final_opening, valid=valid,
                          clearance_mm=jnp.minimum(clearances[0], clearances[1]))


def predicted_evidence(heightmap: Float[Array, "R C"], mask: Bool[Array, "R C"], free: Bool[Array, "R C"],
                       gel_size_mm: tuple[float, float], settings: PredictionSettings, *, contact_count: int = 32,
                       free_count: int = 32) -> TouchEvidence:
    """The likelihood's evidence of one predicted touch (as
    :func:`~tactojax.localize._points.touch_evidence` draws it from an observed one): contact
    points (x, y, -height) from the mask, no-contact points (x, y, 0) where ``free``, sensor frame, mm."""
    xy = ray_grid(*gel_size_mm, settings).reshape(-1, 2)
    flat_mask, flat_height = mask.reshape(-1), heightmap.reshape(-1)
    rows, cols = mask.shape
    contact_index, contact_valid = draw_pixels(flat_mask, pixel_priority(rows, cols, 1), contact_count)
    free_index, free_valid = draw_pixels(free.reshape(-1), pixel_priority(rows, cols, 2), free_count)
    contact = jnp.concatenate([xy[contact_index], -flat_height[contact_index, None]], axis=-1)
    free = jnp.concatenate([xy[free_index], jnp.zeros((free_count, 1))], axis=-1)
    touched = jnp.any(flat_mask)
    return TouchEvidence(contact=contact, contact_valid=contact_valid & touched, free=free,
                         free_valid=free_valid & touched)
