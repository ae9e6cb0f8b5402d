"""Tracking between touches: follow a grasped object frame to frame, re-localize only when the fit degrades.

The tracker starts from the pose belief: a :class:`~tactojax.localize.Localizer` fuses the
first settled grasp (both fingers, earlier grasps of the object), and tracking starts from the
belief's best pose. From there, the next frame of the same grasp differs by what the object slid
or turned in between (a fraction of a millimetre and a degree per frame at camera rate), well
inside ICP's basin (about 2 mm / 5 degrees). So the :class:`Tracker` registers each new frame
against the map imprints that saw that part of the surface
(:meth:`~tactojax.localize.LocalizationMap.imprints_near`; no opening filter: the width between
the jaws changes as the object slides, and the previous pose already says where to look) and
skips the feature network and the belief. ICP starts from the previous pose, from the pose
predicted by the last frame's motion (a slide carries on), and from that prediction shifted by
``TrackingSettings.search_mm`` in the gel plane, each for ``TrackingSettings.icp_iterations``
steps; the fit with the lowest :func:`selection_cost` wins. The shifted starts matter on
surfaces that do not pin the contact down in the plane (a flat blade, along a cylinder): there
the residual is as good anywhere nearby, but the share of the touch the map covers is not.

It re-localizes, with a new belief from the current frame's touch, when the track is lost: the
tracked fit's residual exceeds ``TrackingSettings.max_residual_mm`` (the touch no longer lies on
the map's surface). Where too few points find a match (the map has a hole or an edge there) the
map says nothing: the track holds its pose, and after ``max_unsupported_frames`` such frames in a
row a re-localization is tried. A re-localization replaces the track only if it fits clearly
better (``degraded_mm``), as a far-away pose that fits about as well is more likely a look-alike
than a jump. A touch smaller than ``min_relocalize_px`` contact pixels never re-localizes a
followed object: a pinpoint contact fits many places about equally well. A frame without contact
ends the track (the grasp is over); the belief keeps the grasps so far, and the next settled grasp
is fused with them and starts a new track. :meth:`Tracker.reset` forgets everything.

Registration is against the map, not against the previous frame, so errors do not add up from
frame to frame; what can drift is a slide along a direction the surface does not constrain
(along a cylinder's axis, across a flat face), where the fit stays good while the pose lags.
Every program (the localizer's, and one tracking program per map) is compiled at start-up.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.features import Encoder
from tactojax.localize._belief import BeliefSettings
from tactojax.localize._compile import top_level_jit
from tactojax.localize._correspondences import valid_centroid
from tactojax.localize._icp import IcpSettings, icp
from tactojax.localize._localizer import Frame, LiveEstimate, Localizer, LiveSettings, check_gripper_pose
from tactojax.localize._map import BeliefCalibration, LocalizationMap, Touch
from tactojax.localize._points import POINTS_PER_TOUCH, contact_points
from tactojax.localize._pose import PoseEstimate
from tactojax.localize._surface import MapSurface
from tactojax.mapping import TactileMap
from tactojax.shape import ShapeModel

OVERLAP_WEIGHT_MM = 1.0
"""Selection cost of a fit: score (mm) + this x (1 - overlap)."""


def selection_cost(estimate: PoseEstimate, *, overlap_weight_mm: float = OVERLAP_WEIGHT_MM) -> jax.Array:
    """Cost used to pick among registrations: robust residual RMS plus a penalty for points
    left without a match (mm). Lower is better."""
    return estimate.score + overlap_weight_mm * (1.0 - estimate.overlap)


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
    min_relocalize_px: int = POINTS_PER_TOUCH
    """A followed touch with fewer contact pixels never re-localizes: the track is kept (or held
    where the map has nothing) and such frames do not count towards ``max_unsupported_frames``.
    A contact this small (128 px: 5 mm² at 0.2 mm/px, the query's point budget) fits many places
    on an object about equally well, so a re-localization from it is a guess, while the track
    is at least where the object was. Chosen before measuring."""
    search_mm: float = 1.0
    """Besides the previous pose and the constant-velocity prediction, ICP also starts from the
    prediction shifted by this much along each of the gel's two in-plane axes (0: no shifted
    starts); the start whose fit has the lowest :func:`selection_cost` wins.
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
    (:func:`selection_cost`: residual plus 1 mm x the unmatched fraction)
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


def tracking_starts(T_previous: jaxlie.SE3, T_predicted: jaxlie.SE3, search_mm: float) -> jaxlie.SE3:
    """(S,) ICP starts of a tracked frame: the previous pose, the prediction, and the prediction
    shifted by ``search_mm`` along the sensor's +x, -x, +y, -y (the gel plane; none if 0)."""
    shifts = [(0.0, 0.0)] + ([(search_mm, 0.0), (-search_mm, 0.0), (0.0, search_mm), (0.0, -search_mm)]
                             if search_mm > 0 else [])
    shifted = [T_predicted @ jaxlie.SE3.from_translation(jnp.array([dx, dy, 0.0])) for dx, dy in shifts]
    return jax.tree.map(lambda *x: jnp.stack(x), T_previous, *shifted)


def track_pose(
    view: LocalizationMap, touch: Touch, T_previous: jaxlie.SE3, motion: jaxlie.SE3 | None = None, *,
    tracking: TrackingSettings = TrackingSettings(), settings: IcpSettings = IcpSettings(),
    points_per_touch: int = POINTS_PER_TOUCH,
) -> PoseEstimate:
    """Register a touch from the previous frame's pose against the imprints around it.

    ICP runs from each of :func:`tracking_starts` (the previous pose, the previous pose moved by
    ``motion`` as between the last two frames, and that prediction shifted in the gel plane)
    against the same imprints, and the fit with the lowest
    :func:`selection_cost` among those with matches is returned.

    Args:
        view: the map of the tracked object.
        touch: the touch (heightmap and mask are read; feature and opening are not).
        T_previous: the previous frame's sensor pose in the object frame, mm.
        motion: the sensor's motion over the last frame, in its own frame
            (``T_before.inverse() @ T_previous``); None: standing still.
        tracking, settings: tracking and ICP parameters (``tracking.icp_iterations`` replaces
            ``settings.iterations``).
        points_per_touch: contact points drawn from the touch.

    Returns:
        the estimate (``imprint_index``: the nearest imprint registered against; -1 and not
        converged when no imprint qualifies).
    """
    T_predicted = T_previous if motion is None else T_previous @ motion
    points, points_valid = contact_points(touch, view.mm_per_px, points_per_touch)
    centre = T_predicted @ valid_centroid(points, points_valid)
    around, around_valid = view.imprints_near(T_predicted, centre, tracking.neighbours,
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


def _track_frame(view: LocalizationMap, touch: Touch, T_previous: jaxlie.SE3, T_before: jaxlie.SE3, *,
                 tracking: TrackingSettings, settings: IcpSettings):
    """One followed frame: the tracked fit (held at ``T_previous`` where it has no matches),
    whether it had matches, and whether the touch is large enough to re-localize from."""
    estimate = track_pose(view, touch, T_previous, T_before.inverse() @ T_previous, tracking=tracking,
                          settings=settings)
    points = jnp.minimum(jnp.sum(touch.mask), POINTS_PER_TOUCH)
    matched = (estimate.imprint_index >= 0) & (estimate.overlap * points >= settings.min_correspondences)
    held = PoseEstimate.failed(T_previous, jnp.maximum(estimate.imprint_index, 0))
    estimate = jax.tree.map(lambda fit, hold: jnp.where(matched, fit, hold), estimate, held)
    return estimate, matched, jnp.sum(touch.mask) >= tracking.min_relocalize_px


class Tracker:
    """Follow a grasped object frame to frame from the pose belief; re-localize only when needed
    (see the module docstring).

    The stateful sibling of :class:`~tactojax.localize.Localizer`, with the same arguments and
    calls: ``tracker(image, opening_mm, T_world_gripper)`` returns a :class:`LiveEstimate` whose
    ``tracked`` says whether the pose was followed from the previous frame. Until the first grasp
    settles, frames go to the localizer. On a tracked frame the object probabilities and
    ``probability_within`` are the belief's at the grasp the track started from. Not
    thread-safe: give each thread its own.

    Args:
        maps, model, encoder, calibrations, surfaces, settings, live: as :class:`~tactojax.localize.Localizer`.
        tracking: how the pose is followed.
        icp: the tracked registration's parameters.
    """

    def __init__(self, maps: Sequence[TactileMap], model: ShapeModel, encoder: Encoder, *,
                 calibrations: Sequence[BeliefCalibration | None] | None = None,
                 surfaces: Sequence[MapSurface | None] | None = None,
                 settings: BeliefSettings = BeliefSettings(), live: LiveSettings = LiveSettings(),
                 tracking: TrackingSettings = TrackingSettings(), icp: IcpSettings = IcpSettings()):
        self.localizer = Localizer(maps, model, encoder, calibrations=calibrations, surfaces=surfaces,
                                   settings=settings, live=live)
        """The localizer that finds the pose the track starts from (its belief)."""
        self.tracking = tracking
        self.object_ids, self.image_shape = self.localizer.object_ids, self.localizer.image_shape
        start = time.perf_counter()
        touch = Touch(heightmap=jax.ShapeDtypeStruct(model.image_shape, jnp.float32),
                      mask=jax.ShapeDtypeStruct(model.image_shape, jnp.bool_), feature=_NO_FEATURE,
                      opening=_NO_OPENING)
        pose = jaxlie.SE3(jax.ShapeDtypeStruct((7,), jnp.float32))
        frame = top_level_jit(lambda stack, m, *args: _track_frame(stack.view(m), *args, tracking=tracking,
                                                                   settings=icp))
        # On the map's window of the localizer's stack: one compilation serves every map.
        self._track = frame.lower(self.localizer.stack, np.int32(0), touch, pose, pose).compile()
        self.compile_s = self.localizer.compile_s + time.perf_counter() - start
        """Seconds spent compiling at start-up."""
        self.relocalizations = 0
        """Beliefs the track started from (first grasps included)."""
        self.tracked_frames = 0
        """Frames whose pose was followed from the previous one."""
        self.reset()

    def reset(self) -> None:
        """Forget the track and the belief: the next grasp is localized from nothing."""
        self.localizer.reset()
        self._previous: tuple[int, np.ndarray] | None = None
        self._before: np.ndarray | None = None  # the pose a frame earlier, for the motion
        self._unsupported = 0
        self._belief_numbers = ({}, 0.0)

    def start(self, object_id: str, T_object_sensor: jaxlie.SE3) -> None:
        """Follow from a known pose: the next frame is tracked from ``T_object_sensor`` in the
        map of ``object_id`` (e.g. a pose known from vision at the grasp, or a benchmark's truth)."""
        if object_id not in self.object_ids:
            raise ValueError(f"no map of {object_id!r}; the tracker has {', '.join(self.object_ids)}")
        pose = check_gripper_pose(T_object_sensor)
        self._previous = (self.object_ids.index(object_id), pose)
        self._before = None
        self._unsupported = 0
        self._belief_numbers = ({name: float(name == object_id) for name in self.object_ids}, 1.0)

    def wait(self) -> None:
        """:meth:`Localizer.wait`."""
        self.localizer.wait()

    def close(self) -> None:
        """:meth:`Localizer.close`."""
        self.localizer.close()

    @property
    def following(self) -> bool:
        """Whether the next frame will be tracked from the last pose (a track is held)."""
        return self._previous is not None

    def __call__(self, image: np.ndarray, opening_mm: float, T_world_gripper: jaxlie.SE3 | None = None,
                 second_image: np.ndarray | None = None) -> LiveEstimate:
        """Track (or localize) one frame; the arguments of :meth:`Localizer.__call__`."""
        start = time.perf_counter()
        frame = self.localizer.observe_frame(image, opening_mm, T_world_gripper, second_image)
        if self._previous is None:
            estimate = self.localizer.advance(frame, start)
            if estimate.updated:
                self._start_from_belief(estimate)
            return estimate
        if not frame.contact:  # released: the track ends, the belief stays (the object stays put)
            self._previous, self._before, self._unsupported = None, None, 0
            return self.localizer.advance(frame, start)
        chosen, T_previous = self._previous
        T_before = self._before if self._before is not None else T_previous
        touch = Touch(heightmap=frame.heightmap, mask=frame.mask, feature=_NO_FEATURE, opening=_NO_OPENING)
        tracked, matched, informative = jax.device_get(self._track(
            self.localizer.stack, np.int32(chosen), touch, jaxlie.SE3(T_previous), jaxlie.SE3(T_before)))
        lost = informative & ((self._unsupported >= self.tracking.max_unsupported_frames)
                              | (matched & (tracked.score > self.tracking.max_residual_mm)))
        self._unsupported = 0 if matched else self._unsupported + int(informative)
        if lost:
            relocalized = self._relocalize(frame, tracked, bool(matched), start)
            if relocalized is not None:
                return relocalized
        self.tracked_frames += 1
        pose = np.asarray(tracked.T_object_sensor.wxyz_xyz, np.float32)
        self._before, self._previous = T_previous, (chosen, pose)
        return self._estimate(chosen, frame.gripper, frame.opening_mm, float(tracked.score), start)

    def _start_from_belief(self, estimate: LiveEstimate) -> None:
        """Follow from the belief's best pose of this frame's sensor (the grasp just fused)."""
        if estimate.object_id is None or estimate.T_object_sensor is None:
            return
        self.relocalizations += 1
        self._previous = (self.object_ids.index(estimate.object_id),
                          np.asarray(estimate.T_object_sensor.wxyz_xyz, np.float32))
        self._before, self._unsupported = None, 0
        self._belief_numbers = (estimate.object_probabilities, estimate.probability_within)

    def _relocalize(self, frame: Frame, tracked: PoseEstimate, matched: bool, start: float) -> LiveEstimate | None:
        """A new belief from this frame; it replaces the lost track if it fits clearly better
        (registered from the belief's pose as a tracked frame is). None: the track stays."""
        self.localizer.reset()
        estimate = self.localizer.fuse_frame(frame, start)
        if estimate.T_object_sensor is None:
            return None
        new = self.object_ids.index(estimate.object_id)
        T_belief = np.asarray(estimate.T_object_sensor.wxyz_xyz, np.float32)
        touch = Touch(heightmap=frame.heightmap, mask=frame.mask, feature=_NO_FEATURE, opening=_NO_OPENING)
        fit, fit_matched, _ = jax.device_get(self._track(self.localizer.stack, np.int32(new), touch,
                                                         jaxlie.SE3(T_belief), jaxlie.SE3(T_belief)))
        better = not matched or float(selection_cost(fit)) + self.tracking.degraded_mm < float(selection_cost(tracked))
        if not (fit_matched and better):
            return None
        self.relocalizations += 1
        self._previous, self._before, self._unsupported = (new, np.asarray(fit.T_object_sensor.wxyz_xyz, np.float32)), None, 0
        self._belief_numbers = (estimate.object_probabilities, estimate.probability_within)
        return dataclasses.replace(estimate, T_object_sensor=jaxlie.SE3(self._previous[1]),
                                   residual_mm=float(fit.score))

    def _estimate(self, chosen, gripper, opening_mm, residual_mm, start) -> LiveEstimate:
        """A tracked frame's estimate."""
        probabilities, within = self._belief_numbers
        T_object_sensor = jaxlie.SE3(self._previous[1])
        T_world_object = None
        if gripper is not None:  # the compiled kinematics: no eager pose arithmetic per frame
            T_world_object = jaxlie.SE3(self.localizer._poses(gripper, opening_mm, None, self._previous[1])[3])
        return LiveEstimate(object_id=self.object_ids[chosen], object_probabilities=probabilities,
                            T_object_sensor=T_object_sensor, T_world_object=T_world_object, probability_within=within,
                            modes=(), contact=True, grasps=self.localizer.grasps, updated=False,
                            latency_s=time.perf_counter() - start, tracked=True, residual_mm=residual_mm)


_NO_FEATURE = np.zeros((), np.float32)
"""A tracked frame's touch has no features (NumPy: no device operation per frame)."""
_NO_OPENING = np.float32(0.0)
