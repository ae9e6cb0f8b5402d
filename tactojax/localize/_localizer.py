"""The live localizer: camera frames and gripper poses in; object, pose and confidence out.

A control loop calls :class:`Localizer` once per camera frame, with the gripper's pose and
opening at that frame (and the second finger's frame on a two-sensor gripper). Each frame runs
one precompiled program (heightmap prediction, section IV, and whether the gel is touched),
or none on a frame without a clear colour change against the background, which cannot show
contact (:func:`~tactojax.mapping.may_show_contact`, on the host). When a grasp has
*settled* (``LiveSettings.settle_frames`` frames in contact with the gripper at rest), its
touches (one per finger) update every map's pose belief once, with features from the encoder.
A grasp lasts until a frame shows no contact (the gripper opened); only its first settled
state counts, as the gripper may then carry the object. Successive grasps of an
object that stays put between them are fused by their sensor poses (the kinematics);
:meth:`Localizer.reset` forgets them (the object was moved, or another one is grasped). Between
updates every frame reports the belief as it stands, the sensor pose moved with the gripper.

An update takes tens of milliseconds on a CPU, several camera frames. With
``LiveSettings(background_update=True)`` (what ``tactojax localize-live`` uses on a live
camera, and the live benchmark) it runs in a worker thread: the frame that settles a grasp returns at once, the
frames meanwhile report the belief as it stood (``LiveEstimate.pending``), and the first frame
after the update has finished reports it (``updated``). The camera loop then never waits for
the belief.

Several maps: each keeps its own belief, all under one calibration, so their evidences compare:
P(object) is their softmax (:func:`~tactojax.localize.evaluation.identify_episodes` does the same offline).
After every grasp the least probable maps, together at most ``LiveSettings.object_tolerance`` of
P(object), drop out until :meth:`Localizer.reset`: the first grasp runs every map's belief, the
later ones only those of the objects still in play.

Every program is compiled when the localizer is built (fixed image size, map sizes and
settings) and accepts only arrays of the shapes it was built for, so a frame can never
recompile; a wrong image raises a clear ``ValueError`` before it reaches JAX.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.features import Encoder
from tactojax.features import encode_image
from tactojax.features._encoder import apply_encoder
from tactojax.geometry._kinematics import as_host_pose, compose_on_host, finger_poses_on_host, inverse_on_host
from tactojax.localize._active import ActiveSettings, observe_failed_grasp
from tactojax.localize._belief import BeliefSettings, PoseBelief, belief_digest, empty_belief
from tactojax.localize._compile import top_level_jit
from tactojax.localize._identify_episodes import (OBJECT_TOLERANCE, likely_objects, object_probabilities,
                                                  shared_calibration)
from tactojax.localize._localize import update_program
from tactojax.localize._map import BeliefCalibration, LocalizationMap, Touch, _strong
from tactojax.localize._stacked_maps import StackedMaps
from tactojax.localize._predict_touch import StackedMarchingGrids, map_marching_grid
from tactojax.localize._surface import MapSurface
from tactojax.mapping import TactileMap, may_show_contact, observed_contact, shows_contact
from tactojax.shape import ShapeModel, coordinate_bias, predict


class Frame(NamedTuple):
    """One checked and observed camera frame (:meth:`Localizer.observe_frame`)."""

    image: np.ndarray
    """(H, W, 3) uint8, the sensor finger's."""
    second_image: np.ndarray | None
    """The opposite finger's, if it has a sensor."""
    opening_mm: float
    gripper: np.ndarray | None
    """The gripper's pose, (7,) wxyz_xyz, mm (None: not given)."""
    heightmap: jax.Array | None
    """(H, W) predicted heightmap, mm (None on a frame without a clear colour change, which
    shows no contact: the shape model does not run on it)."""
    mask: jax.Array | None
    """(H, W) contact mask (None where ``heightmap`` is)."""
    contact: bool
    """Whether the frame shows a touch."""


@dataclass(frozen=True)
class LiveSettings:
    """When a grasp counts as settled (static)."""

    settle_frames: int = 3
    """Frames in contact with the gripper at rest before a grasp updates the belief (once)."""
    still_mm: float = 0.2
    """The gripper is at rest when it moves less than this between frames, mm..."""
    still_deg: float = 0.5
    """...turns less than this, degrees..."""
    still_opening_mm: float = 0.1
    """...and its opening changes less than this, mm."""
    modes: int = 3
    """Modes of the belief a :class:`LiveEstimate` reports."""
    background_update: bool = False
    """Run a settled grasp's belief update in a worker thread, so that no frame waits for it
    (see the module docstring); :meth:`Localizer.fuse` still updates at once."""
    object_tolerance: float = OBJECT_TOLERANCE
    """P(object) a grasp may drop: after it, the least probable maps that together hold at most
    this much are no longer updated (P(object) 0) until :meth:`Localizer.reset` (0: every map
    stays; :func:`~tactojax.localize.evaluation.likely_objects`)."""

    def __post_init__(self):
        if self.settle_frames < 1:
            raise ValueError(f"settle_frames must be >= 1, got {self.settle_frames}")
        if not 0.0 <= self.object_tolerance < 1.0:
            raise ValueError(f"object_tolerance must be in [0, 1), got {self.object_tolerance}")


@dataclass(frozen=True)
class LiveEstimate:
    """What the localizer believes after one frame (host-side numbers, ready to log or publish).

    Before the first settled grasp there is no estimate: ``object_id``, ``T_object_sensor`` and
    ``T_world_object`` are None and the probabilities 0. Check ``estimate.T_world_object is
    None`` before using a pose.
    """

    object_id: str | None
    """The most probable object (None before any settled grasp)."""
    object_probabilities: dict[str, float]
    """P(object) of every map (1.0 with a single map once it has a touch; 0 for a map out of play,
    :attr:`Localizer.in_play`)."""
    T_object_sensor: jaxlie.SE3 | None
    """This frame's sensor pose in that object's frame, mm (the belief's best pose, moved with
    the gripper since the grasp that set it)."""
    T_world_object: jaxlie.SE3 | None
    """The object's pose in the world (robot) frame, mm."""
    probability_within: float
    """The belief's calibrated P(its best pose is within 2 mm of the truth)."""
    modes: tuple[tuple[jaxlie.SE3, float], ...]
    """The belief's most probable modes: (T_world_object, probability), most probable first
    (symmetric copies count as one)."""
    contact: bool
    """Whether this frame shows a touch (:func:`tactojax.mapping.shows_contact`)."""
    grasps: int
    """Settled grasps fused into the belief since the last :meth:`Localizer.reset`."""
    updated: bool
    """Whether the belief changed at this frame: a grasp's update landed (at the frame that
    settled it, or, with ``LiveSettings.background_update``, at the first frame after it ran)."""
    latency_s: float
    """Wall time of the call, from image in to estimate out, s."""
    tracked: bool = False
    """Whether a :class:`~tactojax.localize.Tracker` followed the pose from the previous frame."""
    residual_mm: float = 0.0
    """The tracked fit's robust RMS residual, mm (0 unless ``tracked``)."""
    pending: bool = False
    """Whether a settled grasp's update is still running in the background
    (``LiveSettings.background_update``): the estimate is the belief from before that grasp."""

    def as_dict(self) -> dict:
        """JSON-ready fields (poses as wxyz + xyz, mm; null without an estimate)."""
        def pose(T):
            return None if T is None else np.asarray(T.wxyz_xyz).round(6).tolist()
        return {"object_id": self.object_id, "object_probabilities": self.object_probabilities,
                "T_object_sensor_wxyz_xyz": pose(self.T_object_sensor),
                "T_world_object_wxyz_xyz": pose(self.T_world_object),
                "probability_within_2mm": self.probability_within,
                "modes": [{"T_world_object_wxyz_xyz": pose(T), "probability": p} for T, p in self.modes],
                "contact": self.contact, "grasps": self.grasps, "updated": self.updated,
                "latency_s": self.latency_s, "tracked": self.tracked, "residual_mm": self.residual_mm,
                "pending": self.pending}


def observe(model: ShapeModel, image: jax.Array,
            coordinate_bias: jax.Array | None = None) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """A frame's pixels (H, W, 3) in [0, 1], heightmap (H, W) mm, contact mask (H, W) and
    whether it shows a touch at all (:func:`tactojax.mapping.shows_contact`).

    ``coordinate_bias``: :func:`tactojax.shape.coordinate_bias` of ``model``, computed once."""
    pixels = image.astype(jnp.float32) / 255.0
    heightmap, mask = predict(model, pixels, coordinate_bias)
    mask = observed_contact(pixels, model.background, mask, model.mm_per_px)
    return pixels, heightmap, mask, shows_contact(pixels, model.background, mask)


_observe = jax.jit(observe)
"""One compiled program per shape model (its arrays are arguments): a frame's observation, not
dozens of dispatched operations."""


def touch_from_image(model: ShapeModel, encoder: Encoder, image: np.ndarray, opening_mm: float) -> Touch:
    """A touch from one raw tactile frame: the heightmap the shape model predicts (section IV),
    the contact mask the frame shows, and the encoder's features.

    Args:
        model: the sensor's shape model; encoder: the maps' retrieval encoder.
        image: (H, W, 3) uint8 RGB frame (rectified, the shape model's size).
        opening_mm: the gripper opening at the frame, mm.

    Raises:
        ValueError: a frame of the wrong size or type, or an opening that is not a positive number.
    """
    image = check_frame(image, opening_mm, (*model.image_shape, 3))
    _, heightmap, mask, _ = _observe(model, jnp.asarray(image))
    return Touch(heightmap=heightmap, mask=mask, feature=encode_image(encoder, image), opening=np.float32(opening_mm))


def check_maps(maps: Sequence[TactileMap], model: ShapeModel, encoder: Encoder) -> list[TactileMap]:
    """The maps as a list, after a ValueError naming the first that the model or encoder cannot serve."""
    maps = list(maps)
    if not maps:
        raise ValueError("the localizer needs at least one map")
    for tactile_map in maps:
        if tactile_map.features.shape[1] != encoder.feature_dim:
            raise ValueError(f"map {tactile_map.object_id!r} stores {tactile_map.features.shape[1]}-long "
                             f"features but the encoder gives {encoder.feature_dim}: build the map's "
                             "features with this encoder (TactileMap.with_features)")
        if not math.isclose(float(tactile_map.mm_per_px), float(model.mm_per_px), rel_tol=1e-6):
            raise ValueError(f"map {tactile_map.object_id!r} has {tactile_map.mm_per_px} mm/px but the "
                             f"shape model {model.mm_per_px} mm/px: they are of different sensors")
    return maps


def check_frame(image: np.ndarray, opening_mm: float, image_shape: tuple[int, ...], name: str = "frame") -> np.ndarray:
    """The frame as an array, after a ValueError naming what is wrong with it or the opening."""
    image = np.asarray(image)
    if image.shape != image_shape or image.dtype != np.uint8:
        raise ValueError(f"the localizer takes {image_shape} uint8 RGB frames, got {image.shape} {image.dtype} "
                         f"({name})")
    if not np.isfinite(opening_mm) or opening_mm <= 0:
        raise ValueError(f"the gripper opening must be a positive number of mm, got {opening_mm}")
    return image


def check_gripper_pose(T_world_gripper) -> np.ndarray | None:
    """The gripper pose as (7,) float32 wxyz_xyz (None stays None), after a ValueError if it is
    not one finite pose."""
    if T_world_gripper is None:
        return None
    pose = np.asarray(T_world_gripper.wxyz_xyz if isinstance(T_world_gripper, jaxlie.SE3) else T_world_gripper,
                      np.float32)
    if pose.shape != (7,) or not np.isfinite(pose).all():
        raise ValueError(f"the gripper pose must be one finite SE3 (wxyz_xyz (7,)), got shape {pose.shape}")
    return pose


def frame_kinematics(gripper: np.ndarray, opening: float, T_world_object: np.ndarray,
                     T_object_sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The poses a frame needs, (7,) float32 wxyz_xyz each, mm: the sensor finger's and the
    opposite finger's ``T_world_sensor`` for a gripper pose and opening
    (:func:`tactojax.geometry.sensor_pose`, :func:`~tactojax.geometry.opposite_sensor_pose`);
    that sensor in the frame of an object at ``T_world_object``; and the object's pose in the
    world when that sensor sits at ``T_object_sensor`` in its frame.

    Plain Python floats (double precision) on the host, through the geometry module's host twins
    of its pose functions: a compiled program's dispatch and read-back cost 0.15-0.2 ms a frame,
    on a CPU and beside a GPU alike, ten times this arithmetic (issue 27)."""
    T_world_sensor, T_world_opposite = finger_poses_on_host(as_host_pose(gripper), float(opening))
    T_object_world = inverse_on_host(as_host_pose(T_world_object))
    T_sensor_object = inverse_on_host(as_host_pose(T_object_sensor))
    poses = (T_world_sensor, T_world_opposite, compose_on_host(T_object_world, T_world_sensor),
             compose_on_host(T_world_sensor, T_sensor_object))
    return tuple(np.array(pose, np.float32) for pose in poses)


def gripper_motion(previous: np.ndarray, gripper: np.ndarray) -> tuple[float, float]:
    """How far (mm) and by how much (degrees) the gripper moved between two poses (7,)
    wxyz_xyz (NumPy: the frame loop's host-side check)."""
    q0, q1 = np.asarray(previous[:4], np.float64), np.asarray(gripper[:4], np.float64)
    cosine = abs(q0 @ q1) / max(np.linalg.norm(q0) * np.linalg.norm(q1), 1e-12)
    angle = 2.0 * np.arccos(min(cosine, 1.0))
    return float(np.linalg.norm(np.asarray(gripper[4:], np.float64) - previous[4:])), float(np.rad2deg(angle))


class Localizer:
    """Identify and localize a grasped object from camera frames, at camera rate (see the module docstring).

    Built once at start-up (this compiles, typically 10-60 s on a CPU); each frame then runs
    precompiled programs only. Not thread-safe: give each thread its own (with
    ``background_update`` it runs its updates in one worker thread of its own; :meth:`close`
    stops it).

    Args:
        maps: the object maps (features filled by ``encoder``; all of one sensor).
        model: the shape model of the sensor.
        encoder: the feature encoder the maps were built with.
        calibrations: each map's belief calibration (``tactojax calibrate-belief``; None:
            uncalibrated). With several maps all beliefs run under their median
            (:func:`~tactojax.localize.shared_calibration`), so that P(object) compares them.
        surfaces: each map's surface when built before (a map file stores its own:
            :func:`~tactojax.io.stored_surface`); None, or a None entry: built now (1-4 s a map).
        settings: the belief's parameters.
        live: when a grasp counts as settled.
    """

    def __init__(self, maps: Sequence[TactileMap], model: ShapeModel, encoder: Encoder, *,
                 calibrations: Sequence[BeliefCalibration | None] | None = None,
                 surfaces: Sequence[MapSurface | None] | None = None,
                 settings: BeliefSettings = BeliefSettings(), live: LiveSettings = LiveSettings()):
        maps = check_maps(maps, model, encoder)
        calibrations = [None] * len(maps) if calibrations is None else list(calibrations)
        if len(calibrations) != len(maps):
            raise ValueError(f"{len(maps)} maps but {len(calibrations)} calibrations")
        surfaces = [None] * len(maps) if surfaces is None else list(surfaces)
        if len(surfaces) != len(maps):
            raise ValueError(f"{len(maps)} maps but {len(surfaces)} surfaces")
        if len(maps) > 1:
            calibrations = [shared_calibration(calibrations)] * len(maps)
        self.object_ids = tuple(m.object_id for m in maps)
        self.image_shape = (*model.image_shape, 3)
        self.settings, self.live = settings, live
        self.stack = StackedMaps.from_maps([LocalizationMap.from_tactile_map(m, calibration=c, surface=s)
                                            for m, c, s in zip(maps, calibrations, surfaces)])
        """The maps as localization reads them, in one structure (:meth:`StackedMaps.map` gives map
        ``m`` as it was built, :meth:`StackedMaps.window` its window of the stack)."""
        start = time.perf_counter()
        image = jax.ShapeDtypeStruct(self.image_shape, jnp.uint8)
        # On the device once (a model of NumPy arrays would be copied to an accelerator every frame).
        self._model = jax.device_put((model, jax.jit(coordinate_bias)(model)))
        self._background = np.asarray(model.background, np.float32)  # on the host: may_show_contact
        self._observe = jax.jit(lambda model, bias, image: observe(model, image, bias)[1:]).lower(
            *self._model, image).compile()
        self._encoder = encoder
        self._encode = jax.jit(lambda encoder, image: apply_encoder(encoder, image[None].astype(jnp.float32) / 255.0)[0]
                               ).lower(encoder, image).compile()
        example_touch = Touch(heightmap=jax.ShapeDtypeStruct(model.image_shape, jnp.float32),
                              mask=jax.ShapeDtypeStruct(model.image_shape, jnp.bool_),
                              feature=jax.ShapeDtypeStruct((encoder.feature_dim,), jnp.float32),
                              opening=jax.ShapeDtypeStruct((), jnp.float32))
        pose = jaxlie.SE3(jax.ShapeDtypeStruct((7,), jnp.float32))
        # Strongly typed, as every updated belief is (a weak type would not match them). Every
        # map's window of the stack has one shape: its belief too, and one compilation serves them all.
        empty = top_level_jit(lambda stack, m: jax.tree.map(_strong, empty_belief(stack.view(m), settings)))
        self._empty = tuple(empty(self.stack, np.int32(m)) for m in range(len(self.stack)))
        # The program every per-touch update runs (localize's), on the map's window of the stack.
        self._update = top_level_jit(_stacked_update, static_argnums=6).lower(
            self.stack, np.int32(0), self._empty[0], example_touch, pose, np.int32(-1), settings).compile()
        self._summarise = belief_digest.lower(self._empty[0], live.modes).compile()
        self.compile_s = time.perf_counter() - start
        """Seconds spent compiling at start-up."""
        self._worker: ThreadPoolExecutor | None = None
        self._pending: Future | None = None
        self._grids = None  # the maps' marching grids (active touch)
        self._failed = None  # (settings, compiled observe_failed_grasp)
        self.reset()

    def reset(self) -> None:
        """Forget every touch: the object was released, moved or replaced (an update still
        running in the background is waited for and dropped)."""
        if self._pending is not None:
            self._pending.result()
            self._pending = None
        self._fresh = False  # an update landed that no estimate has reported yet
        self.beliefs = list(self._empty)
        """Every map's :class:`~tactojax.localize.PoseBelief` (inspect, plot, or save it); a map
        out of play (:attr:`in_play`) keeps the belief it had when it dropped out."""
        self.in_play = np.ones(len(self.stack), bool)
        """(M,) the maps a grasp updates: those not yet ruled out since the reset
        (:attr:`LiveSettings.object_tolerance`)."""
        self.grasps = 0
        self._summary = None
        self._previous = None  # (gripper pose or None, opening) of the previous contact frame
        self._at_rest = 0
        self._grasp_used = False
        self._poses_known = True

    def __call__(self, image: np.ndarray, opening_mm: float, T_world_gripper: jaxlie.SE3 | None = None,
                 second_image: np.ndarray | None = None) -> LiveEstimate:
        """One frame.

        Args:
            image: (H, W, 3) uint8 RGB frame of the sensor finger (rectified, the shape model's size).
            opening_mm: gripper opening at the frame, mm.
            T_world_gripper: the gripper's pose at the frame (:mod:`tactojax.geometry`'s gripper
                frame), mm, in a frame where the object stays put between grasps. Without it
                grasps cannot be related: each settled grasp starts a new belief.
            second_image: the opposite finger's frame at the same instant, if it has a sensor.
        """
        start = time.perf_counter()
        return self.advance(self.observe_frame(image, opening_mm, T_world_gripper, second_image), start)

    def fuse(self, image: np.ndarray, opening_mm: float, T_world_gripper: jaxlie.SE3 | None = None,
             second_image: np.ndarray | None = None) -> LiveEstimate:
        """Update the belief with this frame's grasp now, without waiting for it to settle (when
        the robot knows its grasp is done); a frame without contact changes nothing. The same
        arguments as a call."""
        start = time.perf_counter()
        return self.fuse_frame(self.observe_frame(image, opening_mm, T_world_gripper, second_image), start)

    def observe_frame(self, image: np.ndarray, opening_mm: float, T_world_gripper: jaxlie.SE3 | None = None,
                      second_image: np.ndarray | None = None) -> Frame:
        """One frame checked (ValueError for a bad image, opening or pose) and observed: its
        predicted heightmap and contact mask, and whether it shows a touch (one compiled program;
        none on a frame without a clear colour change, :func:`tactojax.mapping.may_show_contact`)."""
        image = check_frame(image, opening_mm, self.image_shape)
        if second_image is not None:
            second_image = check_frame(second_image, opening_mm, self.image_shape, "second_image")
        gripper = check_gripper_pose(T_world_gripper)
        if not may_show_contact(image, self._background):
            return Frame(image, second_image, opening_mm, gripper, None, None, False)
        heightmap, mask, contact = self._observe(*self._model, image)
        return Frame(image, second_image, opening_mm, gripper, heightmap, mask, bool(contact))

    def advance(self, frame: Frame, start: float) -> LiveEstimate:
        """A call's work on an observed frame (:meth:`observe_frame`): the grasp's settling, and
        its update once it has settled. ``start``: when the frame arrived (``time.perf_counter``)."""
        self._collect(wait=False)
        if not frame.contact:
            self._previous, self._at_rest, self._grasp_used = None, 0, False
        else:
            self._at_rest = self._at_rest + 1 if self._still(frame.gripper, frame.opening_mm) else 1
            self._previous = (frame.gripper, frame.opening_mm)
            if self._at_rest >= self.live.settle_frames and not self._grasp_used:
                self._fuse_grasp(frame, background=self.live.background_update)
                self._grasp_used = True
        return self._estimate(frame.contact, frame.gripper, frame.opening_mm, time.perf_counter() - start)

    def fuse_frame(self, frame: Frame, start: float) -> LiveEstimate:
        """:meth:`fuse` on an observed frame (:meth:`observe_frame`)."""
        self._collect(wait=True)
        if frame.contact:
            self._fuse_grasp(frame, background=False)
            self._previous, self._grasp_used = (frame.gripper, frame.opening_mm), True
        return self._estimate(frame.contact, frame.gripper, frame.opening_mm, time.perf_counter() - start)

    def wait(self) -> None:
        """Block until an update running in the background has finished (the next estimate
        reports it)."""
        self._collect(wait=True)

    def close(self) -> None:
        """Finish a background update and stop the worker thread (a later update starts it again)."""
        self.wait()
        if self._worker is not None:
            self._worker.shutdown()
            self._worker = None

    def _collect(self, *, wait: bool) -> None:
        """Take a background update's result once it has finished (or wait for it)."""
        if self._pending is not None and (wait or self._pending.done()):
            result, self._pending = self._pending.result(), None
            self._land(*result)

    def _still(self, gripper: np.ndarray | None, opening_mm: float) -> bool:
        """Whether the gripper is at rest since the previous contact frame."""
        if self._previous is None:
            return False
        previous, previous_opening = self._previous
        if abs(opening_mm - previous_opening) > self.live.still_opening_mm:
            return False
        if gripper is None or previous is None:
            return gripper is None and previous is None
        distance, angle = gripper_motion(previous, gripper)
        return distance <= self.live.still_mm and angle <= self.live.still_deg

    def _poses(self, gripper: np.ndarray | None, opening_mm: float, T_world_object: np.ndarray | None = None,
               T_object_sensor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:func:`frame_kinematics` as (7,) float32 NumPy poses; a missing gripper pose is the identity."""
        identity = _IDENTITY
        return frame_kinematics(identity if gripper is None else gripper, opening_mm,
                                identity if T_world_object is None else T_world_object,
                                identity if T_object_sensor is None else T_object_sensor)

    def _fuse_grasp(self, frame: Frame, *, background: bool) -> None:
        """Update the beliefs of the maps in play with this grasp's touches, now or in the worker thread."""
        self._collect(wait=True)  # grasps update in order, each from the belief the last one left
        if frame.gripper is None or not self._poses_known:  # grasps that cannot be related: start over
            if self.grasps:
                self.reset()
            self._poses_known = frame.gripper is not None
        if not background:
            self._land(*self._updated(self.beliefs, self.in_play, frame))
            return
        if self._worker is None:
            self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="tactojax-belief")
        self._pending = self._worker.submit(self._updated, self.beliefs, self.in_play, frame)

    def _updated(self, beliefs: Sequence[PoseBelief], in_play: np.ndarray, frame: Frame):
        """The beliefs of the maps in play after this grasp's touches (sensor finger, then the
        other), what an estimate reports of them (None: no map explains the touches), and the
        maps still in play after it. Touches nothing of ``self`` but its compiled programs (it
        may run in the worker thread)."""
        image, second_image, opening_mm, gripper = frame.image, frame.second_image, frame.opening_mm, frame.gripper
        opening = np.float32(opening_mm)
        T_world_sensor, T_world_opposite, _, _ = self._poses(gripper, opening)
        touches = [(Touch(heightmap=frame.heightmap, mask=frame.mask, feature=self._encode(self._encoder, image),
                          opening=opening),
                    T_world_sensor)]
        if second_image is not None and may_show_contact(second_image, self._background):
            second_heightmap, second_mask, second_contact = self._observe(*self._model, second_image)
            if bool(second_contact):
                touches.append((Touch(heightmap=second_heightmap, mask=second_mask,
                                      feature=self._encode(self._encoder, second_image), opening=opening),
                                T_world_opposite))
        beliefs = list(beliefs)
        for m in np.flatnonzero(in_play):
            for touch, T_world_touch in touches:
                beliefs[m] = self._update(self.stack, np.int32(m), beliefs[m], touch, jaxlie.SE3(T_world_touch),
                                          np.int32(-1))
        return (beliefs, *self._summary_of(beliefs, in_play))

    def observe_failed_grasp(self, T_world_gripper: jaxlie.SE3, settings: ActiveSettings = ActiveSettings()) -> None:
        """A grasp commanded at ``T_world_gripper`` failed (the jaws closed on nothing, or hit the
        object): the belief of every map in play learns where the object is not
        (:func:`~tactojax.localize.active.observe_failed_grasp`), and so does P(object). Before any
        touch it changes nothing. Compiles once per settings (:meth:`prepare_active`).

        Args:
            T_world_gripper: the commanded gripper pose (fully open), mm, in the frame of the
                gripper poses the frames come with.
            settings: the grasp prediction (the active choice's settings).
        """
        self._collect(wait=True)
        if self._summary is None:
            return
        program = self.prepare_active(settings)
        T_world_gripper = jaxlie.SE3(jnp.asarray(T_world_gripper.wxyz_xyz, jnp.float32))
        beliefs = list(self.beliefs)
        for m in np.flatnonzero(self.in_play):
            beliefs[m] = program(self.stack, np.int32(m), self.marching_grids(), beliefs[m], T_world_gripper)
        self.beliefs, (self._summary, self.in_play) = beliefs, self._summary_of(beliefs, self.in_play)
        self._fresh = True

    def marching_grids(self) -> StackedMarchingGrids:
        """Every map's :class:`~tactojax.localize.active.MarchingGrid` (what active touch predicts
        grasps with; ``.grid(m)`` gives map ``m``'s), built on first use, each on its map's own
        grid."""
        if self._grids is None:
            self._grids = StackedMarchingGrids.from_grids(map_marching_grid(self.stack.map(m))
                                                          for m in range(len(self.stack)))
        return self._grids

    def prepare_active(self, settings: ActiveSettings = ActiveSettings()):
        """Build the marching grids and compile :meth:`observe_failed_grasp`'s program for
        ``settings`` now (an active episode does at its first choice), so that no grasp of the
        episode compiles. Returns the compiled program."""
        if self._failed is None or self._failed[0] != settings:
            pose = jaxlie.SE3(jax.ShapeDtypeStruct((7,), jnp.float32))
            program = top_level_jit(lambda stack, m, grids, belief, T_world_gripper: observe_failed_grasp(
                stack.view(m), grids.grid(m), belief, T_world_gripper, settings))
            self._failed = (settings, program.lower(self.stack, np.int32(0), self.marching_grids(), self._empty[0],
                                                    pose).compile())
        return self._failed[1]

    def _summary_of(self, beliefs: Sequence[PoseBelief], in_play: np.ndarray):
        """What an estimate reports of the beliefs of the maps in play (None: no map explains
        the touches; the others have P(object) 0), and the maps still in play after it."""
        indices = np.flatnonzero(in_play)
        summaries = dict(zip(indices.tolist(), jax.device_get([self._summarise(beliefs[m]) for m in indices])))
        log_evidence = np.full(len(self.stack), -np.inf)
        for m, summary in summaries.items():
            log_evidence[m] = summary.log_evidence
        probabilities = object_probabilities(log_evidence)
        if not probabilities.any():  # no map explains the touches
            return None, in_play
        chosen = int(np.argmax(probabilities))
        digest = summaries[chosen]
        modes = tuple((jaxlie.SE3(np.asarray(T)), float(p))
                      for T, p in zip(digest.mode_T_world_object, digest.mode_probability) if p > 0)
        summary = (chosen, dict(zip(self.object_ids, probabilities.astype(float).tolist())),
                   np.asarray(digest.T_world_object, np.float32), float(digest.probability_within), modes)
        return summary, in_play & likely_objects(probabilities, self.live.object_tolerance)

    def _land(self, beliefs: list[PoseBelief], summary, in_play: np.ndarray) -> None:
        """An update's result becomes the localizer's belief."""
        self.beliefs, self._summary, self.in_play = beliefs, summary, in_play
        self.grasps += 1
        self._fresh = True

    def _estimate(self, contact: bool, gripper, opening_mm: float, latency_s: float) -> LiveEstimate:
        updated, self._fresh = self._fresh, False
        pending = self._pending is not None
        if self._summary is None:
            return LiveEstimate(object_id=None, object_probabilities={name: 0.0 for name in self.object_ids},
                                T_object_sensor=None, T_world_object=None, probability_within=0.0, modes=(),
                                contact=contact, grasps=self.grasps, updated=updated, latency_s=latency_s,
                                pending=pending)
        chosen, probabilities, T_world_object, within, modes = self._summary
        T_object_sensor = None
        if gripper is not None or not self._poses_known:
            _, _, T_object_sensor, _ = self._poses(gripper, opening_mm, T_world_object)
            T_object_sensor = jaxlie.SE3(T_object_sensor)
        return LiveEstimate(object_id=self.object_ids[chosen], object_probabilities=probabilities,
                            T_object_sensor=T_object_sensor, T_world_object=jaxlie.SE3(T_world_object),
                            probability_within=within, modes=modes, contact=contact, grasps=self.grasps,
                            updated=updated, latency_s=latency_s, pending=pending)


def _stacked_update(stack: StackedMaps, m, belief, touch, T_world_sensor, exclude, settings):
    """:func:`~tactojax.localize._localize.update_program` on map ``m`` of the stack."""
    return update_program(stack.view(m), belief, touch, T_world_sensor, exclude, settings)


_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], np.float32)
