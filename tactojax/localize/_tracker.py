"""Tracking between touches: follow a grasped object frame to frame, re-localize only when the fit degrades.

Once a touch is localized, the next frame of the same grasp differs by what the object slid or
turned in between (a fraction of a millimetre and a degree per frame at camera rate), well
inside ICP's basin (about 2 mm / 5 degrees). So the :class:`Tracker` registers each new frame
against the map imprints that saw that part of the surface (their contact centres nearest to
where the touch lands, facing the same way; no opening filter: the width between the jaws
changes as the object slides, and the previous pose already says where to look) and skips the
feature network and retrieval. ICP starts from the previous pose, from the pose predicted by
the last frame's motion (a slide carries on), and from that prediction shifted by
``TrackingSettings.search_mm`` in the gel plane, each for ``TrackingSettings.icp_iterations``
steps (half a re-localization's: a frame's slip is small); the fit with the lowest
:func:`~tactojax.localize.selection_cost` wins. The shifted starts matter on surfaces that do not
pin the contact down in the plane (a flat blade, along a cylinder): there the residual is as good
anywhere nearby, but the share of the touch the map covers is not.

It re-localizes from nothing, as :class:`~tactojax.localize.Localizer` does, when there is
nothing to follow (the first touch, or the first after a frame without contact) or when the
track is lost: the tracked fit's residual exceeds ``TrackingSettings.max_residual_mm`` (the
touch no longer lies on the map's surface). Where too few points find a match (the map has a
hole or an edge there) the map says nothing: the track holds its pose, and after
``max_unsupported_frames`` such frames in a row a re-localization is tried. A re-localization
replaces the track only if it has matches and fits clearly better (``degraded_mm``), as a
far-away pose that fits about as well is more likely a look-alike than a jump. A touch smaller
than ``min_relocalize_px`` contact pixels never re-localizes a followed object: a pinpoint
contact fits many places about equally well. Neither convergence nor coverage is required of a
tracked frame: ICP sliding along a flat face may not settle within its iterations while the
fit is good, and how much of a touch the nearby imprints cover says more about the map than
about the pose (coverage ranks the starts of one frame; it does not judge the frame).

Registration is against the map, not against the previous frame, so errors do not add up from
frame to frame; what can drift is a slide along a direction the surface does not constrain
(along a cylinder's axis, across a flat face), where the fit stays good while the pose lags.

Tracking and re-localization are one compiled program (``lax.cond``: only the branch taken
runs), so a frame never recompiles and a re-localization reuses the frame's heightmap.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax._compilation import kernel_count
from tactojax.features import Encoder
from tactojax.localize._correspondences import valid_centroid
from tactojax.localize._icp import IcpSettings, icp
from tactojax.localize._identify import MapLibrary
from tactojax.localize._localizer import (LiveEstimate, check_frame, check_live_method,
                                          check_maps, fit_confidence, no_contact, observe, relocalize)
from tactojax.localize._map import LocalizationMap, Query
from tactojax.localize._methods import POINTS_PER_QUERY, Method, query_points
from tactojax.localize._pose import PoseEstimate
from tactojax.localize._register import selection_cost
from tactojax.localize._retrieval import MAX_OPENING_DIFFERENCE_MM
from tactojax.localize._search import SearchSettings
from tactojax.mapping import TactileMap
from tactojax.shape import ShapeModel, coordinate_bias


@dataclass(frozen=True)
class TrackingSettings:
    """How a :class:`Tracker` follows a pose (static: one compilation per setting)."""

    neighbours: int = 10
    """Map imprints a tracked frame is registered against: those nearest where it lands (the
    mapping grid's 3 yaws x 10 mm spacing puts about 6 within 10 mm of any point)."""
    max_facing_deg: float = 60.0
    """Only imprints whose sensor faced the surface within this angle of the tracked sensor's
    direction are registered against (the other side of a thin part is not the same surface)."""
    max_residual_mm: float = 0.25
    """The track is lost when the tracked fit's robust residual RMS exceeds this (the touch no
    longer lies on the map's surface: 5x the shape model's 0.05 mm error on a real sensor).
    Chosen a priori, not tuned on a benchmark."""
    max_unsupported_frames: int = 30
    """Frames in a row the track may hold its pose because the map has nothing at it (fewer
    than ``IcpSettings.min_correspondences`` matches: a hole in the map, an edge) before the
    next frame is re-localized (30: a third to half a second at camera rate)."""
    min_relocalize_px: int = POINTS_PER_QUERY
    """A followed touch with fewer contact pixels never re-localizes: the track is kept (or held
    where the map has nothing) and such frames do not count towards ``max_unsupported_frames``.
    A contact this small (128 px: 5 mm² at 0.2 mm/px, the query's point budget) fits many places
    on an object about equally well, so a re-localization from it is a guess, while the track
    is at least where the object was. Chosen before measuring."""
    search_mm: float = 1.0
    """Besides the previous pose and the constant-velocity prediction, ICP also starts from the
    prediction shifted by this much along each of the gel's two in-plane axes (0: no shifted
    starts); the start whose fit has the lowest :func:`~tactojax.localize.selection_cost` wins.
    On a face the touch does not pin down in the plane (a flat blade, a cylinder's axis) the
    residual cannot tell where the contact lies, but the share of the touch the map covers can:
    a shifted start recovers a slide the residual alone does not see. A fifth of ICP's ~5 mm
    basin, chosen before measuring."""
    icp_iterations: int = 5
    """ICP iterations of a tracked frame (a re-localization keeps ``IcpSettings.iterations``).
    Between frames the object moves by at most a fraction of a millimetre and a degree, which
    ICP closes in a few steps; more only slide further along a face the touch does not pin
    down, at a cost that grows with the starts. Checked against 10 on a development slip seed
    (no less accurate, 1.4x faster), not on the reported one."""
    degraded_mm: float = 0.25
    """A re-localization replaces a lost track only if its cost
    (:func:`~tactojax.localize.selection_cost`: residual plus 1 mm x the unmatched fraction)
    is lower by more than this."""

    def __post_init__(self):
        if self.max_unsupported_frames < 0:
            raise ValueError(f"max_unsupported_frames must be >= 0, got {self.max_unsupported_frames}")
        if self.neighbours < 1:
            raise ValueError(f"tracking needs at least one neighbour imprint, got {self.neighbours}")
        if not 0 < self.max_facing_deg <= 180:
            raise ValueError(f"max_facing_deg must lie in (0, 180], got {self.max_facing_deg}")
        if self.min_relocalize_px < 0:
            raise ValueError(f"min_relocalize_px must be >= 0, got {self.min_relocalize_px}")
        if self.icp_iterations < 1:
            raise ValueError(f"icp_iterations must be >= 1, got {self.icp_iterations}")
        if self.search_mm < 0:
            raise ValueError(f"search_mm must be >= 0, got {self.search_mm}")
        if self.degraded_mm < 0 or self.max_residual_mm <= 0:
            raise ValueError(f"need degraded_mm >= 0 and max_residual_mm > 0, got {self.degraded_mm} and "
                             f"{self.max_residual_mm}")


def imprints_facing(
    view: LocalizationMap, T_object_sensor: jaxlie.SE3, centre: jax.Array, n: int, *, max_facing_deg: float,
) -> tuple[jax.Array, jax.Array]:
    """The n imprints nearest a contact centre that saw it from the same side.

    Args:
        view: the map.
        T_object_sensor: the sensor pose being tracked (object frame, mm).
        centre: (3,) where the touch's contact lands, object frame, mm.
        n: how many imprints.
        max_facing_deg: largest angle between an imprint's sensor axis and the tracked one's.

    Returns:
        (n,) imprint indices, nearest contact centre first, and (n,) which of them are real.
    """
    axis = T_object_sensor.rotation() @ jnp.array([0.0, 0.0, 1.0])
    axes = jax.vmap(lambda R: R @ jnp.array([0.0, 0.0, 1.0]))(view.T_object_sensor.rotation())
    available = view.imprint_valid & (axes @ axis >= jnp.cos(jnp.deg2rad(max_facing_deg)))
    distance = jnp.linalg.norm(view.centres - centre, axis=-1)
    _, nearest = jax.lax.top_k(jnp.where(available, -distance, -jnp.inf), n)
    return nearest, available[nearest]


def tracking_starts(T_previous: jaxlie.SE3, T_predicted: jaxlie.SE3, search_mm: float) -> jaxlie.SE3:
    """(S,) ICP starts of a tracked frame: the previous pose, the prediction, and the prediction
    shifted by ``search_mm`` along the sensor's +x, -x, +y, -y (the gel plane; none if 0)."""
    shifts = [(0.0, 0.0)] + ([(search_mm, 0.0), (-search_mm, 0.0), (0.0, search_mm), (0.0, -search_mm)]
                             if search_mm > 0 else [])
    shifted = [T_predicted @ jaxlie.SE3.from_translation(jnp.array([dx, dy, 0.0])) for dx, dy in shifts]
    return jax.tree.map(lambda *x: jnp.stack(x), T_previous, *shifted)


def track_pose(
    view: LocalizationMap, query: Query, T_previous: jaxlie.SE3, motion: jaxlie.SE3 | None = None, *,
    tracking: TrackingSettings = TrackingSettings(), settings: IcpSettings = IcpSettings(),
    points_per_query: int = POINTS_PER_QUERY,
) -> PoseEstimate:
    """Register a touch from the previous frame's pose against the imprints around it.

    ICP runs from each of :func:`tracking_starts` (the previous pose, the previous pose moved by
    ``motion`` as between the last two frames, and that prediction shifted in the gel plane)
    against the same imprints, and the fit with the lowest
    :func:`~tactojax.localize.selection_cost` among those with matches is returned.

    Args:
        view: the map of the tracked object.
        query: the touch (heightmap and mask are read; feature and opening are not).
        T_previous: the previous frame's sensor pose in the object frame, mm.
        motion: the sensor's motion over the last frame, in its own frame
            (``T_before.inverse() @ T_previous``); None: standing still.
        tracking, settings: tracking and ICP parameters (``tracking.icp_iterations`` replaces
            ``settings.iterations``).
        points_per_query: contact points drawn from the touch.

    Returns:
        the estimate (``imprint_index``: the nearest imprint registered against; -1 and not
        converged when no imprint qualifies).
    """
    T_predicted = T_previous if motion is None else T_previous @ motion
    points, points_valid = query_points(query, view.mm_per_px, points_per_query)
    centre = T_predicted @ valid_centroid(points, points_valid)
    around, around_valid = imprints_facing(view, T_predicted, centre, tracking.neighbours,
                                           max_facing_deg=tracking.max_facing_deg)
    starts = tracking_starts(T_previous, T_predicted, tracking.search_mm)
    run = jax.vmap(icp, in_axes=(None, None, None, None, None, 0, None))
    estimates = run(view, around, around_valid, points, points_valid, starts,
                    dataclasses.replace(settings, iterations=tracking.icp_iterations))
    matched = estimates.overlap * jnp.sum(points_valid) >= settings.min_correspondences
    best = jnp.argmin(jnp.where(matched, selection_cost(estimates), jnp.inf))
    estimate = jax.tree.map(lambda x: x[best], estimates)
    found = around_valid[0]
    return estimate.replace(converged=estimate.converged & found,
                            imprint_index=jnp.where(found, around[0], -1).astype(jnp.int32))


def _track_program(model: ShapeModel, coordinate_bias: jax.Array | None, encoder: Encoder, library: MapLibrary,
                   views: tuple[LocalizationMap, ...], image: jax.Array, opening: jax.Array,
                   T_previous: jaxlie.SE3, T_before: jaxlie.SE3,
                   previous: jax.Array, follow: jax.Array, relocalize_now: jax.Array, *,
                   tracking: TrackingSettings, **options):
    """One frame: track from (previous map, T_previous, moving as from T_before) when ``follow``;
    re-localize when there is no track, when it is lost, or when ``relocalize_now`` (the map
    had nothing at the track for too long; see the module docstring).

    Returns (map index, (M,) best similarities, contact, estimate, tracked, relocalized, whether
    the tracked fit had matches, whether the touch is large enough to re-localize from).
    """
    pixels, heightmap, mask, contact = observe(model, image, coordinate_bias)
    query = Query(heightmap=heightmap, mask=mask, feature=jnp.zeros(()), opening=opening)
    settings = options["settings"]
    motion = T_before.inverse() @ T_previous

    def branch(index):
        return lambda views: track_pose(views[index], query, T_previous, motion, tracking=tracking,
                                        settings=settings, points_per_query=options["points_per_query"])

    tracked = jax.lax.switch(previous, [branch(i) for i in range(len(views))], views)
    points = jnp.minimum(jnp.sum(mask), options["points_per_query"])
    # Too small a touch to re-localize from: keep the track (see min_relocalize_px).
    informative = jnp.sum(mask) >= tracking.min_relocalize_px
    matched = (tracked.imprint_index >= 0) & (tracked.overlap * points >= settings.min_correspondences)
    # Without matches the map has nothing to say here (a hole, an edge): hold the pose.
    tracked = jax.tree.map(lambda fit, held: jnp.where(matched, fit, held), tracked,
                           PoseEstimate.failed(T_previous, jnp.maximum(tracked.imprint_index, 0)))
    keep = follow & (~informative | (~relocalize_now & (~matched | (tracked.score <= tracking.max_residual_mm))))

    def keep_track(_):
        return previous, jnp.zeros(len(views), jnp.float32), tracked, jnp.bool_(True)

    def start_over(_):
        chosen, best, estimate = relocalize(encoder, library, views, pixels, heightmap, mask, opening, **options)
        # A re-localization without matches says nothing: a held track stays. Otherwise it
        # replaces a lost track only if it fits better by degraded_mm (the track has
        # continuity on its side; a smaller difference is noise).
        found = (estimate.imprint_index >= 0) & (estimate.overlap * points >= settings.min_correspondences)
        better = ~matched | (selection_cost(estimate) + tracking.degraded_mm < selection_cost(tracked))
        stay = follow & (tracked.imprint_index >= 0) & ~(found & better)
        chosen = jnp.where(stay, previous, chosen)
        estimate = jax.tree.map(lambda a, b: jnp.where(stay, a, b), tracked, estimate)
        return chosen, best, estimate, stay

    chosen, best, estimate, from_track = jax.lax.cond(keep, keep_track, start_over, None)
    return chosen, best, contact, estimate, from_track, ~keep, matched, informative


class Tracker:
    """Follow a grasped object frame to frame; re-localize only when needed (see the module docstring).

    The stateful sibling of :class:`~tactojax.localize.Localizer`, with the same arguments and
    calls: ``tracker(image, opening_mm)`` returns a :class:`LiveEstimate` whose ``tracked`` says
    whether the pose was followed or found from nothing. A frame without contact ends the track
    (the next touch is localized from nothing); so does :meth:`reset` (e.g. after a regrasp
    that kept touching). On a tracked frame ``similarity`` and ``identity_margin`` are those of
    the localization the track started from. Not thread-safe: give each thread its own.

    Args:
        maps, model, encoder, method, settings, search, points_per_query,
        max_opening_difference_mm: as :class:`~tactojax.localize.Localizer` (for re-localizing).
        tracking: how the pose is followed.
    """

    def __init__(self, maps: Sequence[TactileMap], model: ShapeModel, encoder: Encoder, *,
                 method: str | Method = "cti-icp-5", settings: IcpSettings = IcpSettings(),
                 search: SearchSettings = SearchSettings(), points_per_query: int = POINTS_PER_QUERY,
                 max_opening_difference_mm: float = MAX_OPENING_DIFFERENCE_MM,
                 tracking: TrackingSettings = TrackingSettings()):
        maps = check_maps(maps, model, encoder)
        self.method = check_live_method(method)
        self.tracking = tracking
        self.object_ids = tuple(m.object_id for m in maps)
        self.image_shape = (*model.image_shape, 3)
        self._operands = (model, jax.jit(coordinate_bias)(model), encoder, MapLibrary.from_maps(maps),
                          tuple(LocalizationMap.from_tactile_map(m) for m in maps))
        program = functools.partial(
            _track_program, tracking=tracking, method=self.method, settings=settings, search=search,
            points_per_query=points_per_query, max_opening_difference_mm=max_opening_difference_mm)
        start = time.perf_counter()
        example = (jax.ShapeDtypeStruct(self.image_shape, jnp.uint8), jax.ShapeDtypeStruct((), jnp.float32),
                   jaxlie.SE3(jax.ShapeDtypeStruct((7,), jnp.float32)), jaxlie.SE3(jax.ShapeDtypeStruct((7,), jnp.float32)),
                   jax.ShapeDtypeStruct((), jnp.int32), jax.ShapeDtypeStruct((), jnp.bool_),
                   jax.ShapeDtypeStruct((), jnp.bool_))
        self._compiled = jax.jit(program).lower(*self._operands, *example).compile()
        self.compile_s = time.perf_counter() - start
        """Seconds spent compiling at start-up."""
        self.kernels = kernel_count(self._compiled)
        """Kernels in the compiled program (both branches; a frame runs one of them)."""
        self.relocalizations = 0
        """Frames with contact that ran a re-localization (first touches included)."""
        self.tracked_frames = 0
        """Frames whose pose was followed from the previous one (some after a re-localization
        that fitted worse)."""
        self.reset()

    def reset(self) -> None:
        """Forget the track: the next touch is localized from nothing."""
        self._previous: tuple[int, np.ndarray] | None = None
        self._before: np.ndarray | None = None  # the pose a frame earlier, for the motion
        self._identity = (0.0, 0.0)
        self._unsupported = 0

    def start(self, object_id: str, T_object_sensor: jaxlie.SE3) -> None:
        """Follow from a known pose: the next frame is tracked from ``T_object_sensor`` in the
        map of ``object_id`` (e.g. a pose known from vision at the grasp, or a benchmark's truth)."""
        if object_id not in self.object_ids:
            raise ValueError(f"no map of {object_id!r}; the tracker has {', '.join(self.object_ids)}")
        pose = np.asarray(T_object_sensor.wxyz_xyz, np.float32)
        if pose.shape != (7,) or not np.isfinite(pose).all():
            raise ValueError(f"the start pose must be one finite SE3, got wxyz_xyz of shape {pose.shape}")
        self._previous = (self.object_ids.index(object_id), pose)
        self._before = None
        self._identity = (1.0, 1.0)
        self._unsupported = 0

    @property
    def following(self) -> bool:
        """Whether the next frame will be tracked from the last pose (a track is held)."""
        return self._previous is not None

    def __call__(self, image: np.ndarray, opening_mm: float) -> LiveEstimate:
        """Track (or localize) one frame.

        Args:
            image: (H, W, 3) uint8 RGB frame of the sensor (rectified, the shape model's size).
            opening_mm: gripper opening at the frame, mm.
        """
        start = time.perf_counter()
        image = check_frame(image, opening_mm, self.image_shape)
        previous, T_previous = self._previous if self._previous is not None else (0, _IDENTITY)
        T_before = self._before if self._before is not None else T_previous
        relocalize_now = self._unsupported >= self.tracking.max_unsupported_frames
        chosen, best, contact, estimate, tracked, relocalized, matched, informative = jax.device_get(self._compiled(
            *self._operands, image, np.float32(opening_mm), jaxlie.SE3(T_previous), jaxlie.SE3(T_before),
            np.int32(previous), np.bool_(self._previous is not None), np.bool_(relocalize_now)))
        chosen, contact, tracked, relocalized = int(chosen), bool(contact), bool(tracked), bool(relocalized)
        if not contact:
            self.reset()
            return no_contact(time.perf_counter() - start)
        self.relocalizations += relocalized
        self.tracked_frames += tracked
        if not tracked or matched:
            self._unsupported = 0
        elif informative:  # a touch the map has nothing for at the track
            self._unsupported += 1
        if tracked:
            similarity, margin = self._identity
        else:
            best = np.asarray(best)
            similarity = float(best[chosen]) if np.isfinite(best[chosen]) else -1.0
            others = np.delete(best, chosen)
            others = others[np.isfinite(others)]
            margin = 1.0 if others.size == 0 else similarity - float(others.max())
            self._identity = (similarity, margin)
        registered = int(estimate.imprint_index) >= 0
        pose = np.asarray(estimate.T_object_sensor.wxyz_xyz, np.float32)
        self._before = T_previous if tracked else None
        self._previous = (chosen, pose) if registered else None
        residual, overlap = float(estimate.score), float(estimate.overlap)
        return LiveEstimate(
            object_id=self.object_ids[chosen], T_object_sensor=jaxlie.SE3(pose),
            confidence=float(fit_confidence(residual, overlap, registered)), contact=True, similarity=similarity,
            identity_margin=float(margin), residual_mm=residual, overlap=overlap, converged=bool(estimate.converged),
            latency_s=time.perf_counter() - start, tracked=tracked)


_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], np.float32)
