"""The live localizer: one compiled program from a raw tactile image to object, pose, confidence.

A control loop calls :class:`Localizer` once per camera frame. Everything a touch needs runs
in a single XLA program compiled ahead of time when the localizer is built (fixed image size,
fixed map sizes, fixed method): heightmap prediction (section IV), features, identification
among the maps (section VII), then localization in the chosen object's map (section VI). The
compiled program only accepts arrays of the shapes it was built for, so a call can never
recompile; a wrong image raises a clear ``ValueError`` before it reaches JAX.

Switching maps inside the program uses ``lax.switch``: each map is its own branch operand, so
picking an object costs nothing (no copy of a stacked map).
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax._compilation import kernel_count
from tactojax.features import Encoder
from tactojax.features._encoder import apply_encoder
from tactojax.localize._icp import IcpSettings
from tactojax.localize._identify import MapLibrary, identify
from tactojax.localize._map import LocalizationMap, Query
from tactojax.localize._methods import POINTS_PER_QUERY, Method, localize_query, parse_method
from tactojax.localize._pose import PoseEstimate
from tactojax.localize._retrieval import MAX_OPENING_DIFFERENCE_MM
from tactojax.localize._search import SearchSettings
from tactojax.mapping import TactileMap, observed_contact, shows_contact
from tactojax.shape import ShapeModel, coordinate_bias, predict

CONFIDENT_RESIDUAL_MM = 0.5
"""Fit residual at which :attr:`LiveEstimate.confidence` has dropped to 1/e of the overlap."""


@dataclass(frozen=True)
class LiveEstimate:
    """What the localizer says about one touch (host-side numbers, ready to log or publish).

    A frame without contact (nothing touching, a black frame) has no estimate: ``contact`` is
    False, ``object_id`` and ``T_object_sensor`` are None and the numbers are 0 (``latency_s``
    is still measured). Check ``estimate.contact`` (or ``estimate.T_object_sensor is None``)
    before using the pose.
    """

    object_id: str | None
    """The identified object (the map holding the most similar imprint); None without contact."""
    T_object_sensor: jaxlie.SE3 | None
    """Sensor pose in that object's frame, mm; None without contact."""
    confidence: float
    """A heuristic in [0, 1]: 0 without contact or without a retrieved imprint, else the
    fraction of the touch's points matched in the map times ``exp(-(residual /
    CONFIDENT_RESIDUAL_MM)^2)``. Not a calibrated probability."""
    contact: bool
    """Whether the frame shows a touch (:func:`tactojax.mapping.shows_contact`)."""
    similarity: float
    """Cosine similarity of the closest imprint in the chosen map."""
    identity_margin: float
    """Its lead over the best imprint of any other map (1.0 with a single map)."""
    residual_mm: float
    """Robust RMS point-to-plane residual at the estimate, mm."""
    overlap: float
    """Fraction of the query's points matched in the map at the estimate."""
    converged: bool
    """ICP's step fell below its tolerance within its iterations (a good fit may still be False
    when the iterations ran out first)."""
    latency_s: float
    """Wall time of the call, from image in to estimate out, s."""
    tracked: bool = False
    """Whether a :class:`~tactojax.localize.Tracker` followed the pose from the previous frame
    (False: localized from nothing, as :class:`Localizer` always does)."""

    def as_dict(self) -> dict:
        """JSON-ready fields (the pose as wxyz + xyz, mm; null without contact)."""
        pose = None if self.T_object_sensor is None else np.asarray(self.T_object_sensor.wxyz_xyz).round(6).tolist()
        return {"object_id": self.object_id, "T_object_sensor_wxyz_xyz": pose,
                "confidence": self.confidence, "contact": self.contact, "similarity": self.similarity,
                "identity_margin": self.identity_margin, "residual_mm": self.residual_mm,
                "overlap": self.overlap, "converged": self.converged, "latency_s": self.latency_s,
                "tracked": self.tracked}


def observe(model: ShapeModel, image: jax.Array,
            coordinate_bias: jax.Array | None = None) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """A frame's pixels (H, W, 3) in [0, 1], heightmap (H, W) mm, contact mask (H, W) and
    whether it shows a touch at all (:func:`tactojax.mapping.shows_contact`).

    ``coordinate_bias``: :func:`tactojax.shape.coordinate_bias` of ``model``, computed once."""
    pixels = image.astype(jnp.float32) / 255.0
    heightmap, mask = predict(model, pixels, coordinate_bias)
    mask = observed_contact(pixels, model.background, mask, model.mm_per_px)
    return pixels, heightmap, mask, shows_contact(pixels, model.background, mask)


def relocalize(encoder: Encoder, library: MapLibrary, views: tuple[LocalizationMap, ...], pixels: jax.Array,
               heightmap: jax.Array, mask: jax.Array, opening: jax.Array, *, method: Method, settings: IcpSettings,
               search: SearchSettings, points_per_query: int, max_opening_difference_mm: float):
    """Identify a touch among the maps and localize it in the chosen one, from nothing.

    Returns:
        the chosen map's index, (M,) the best similarity in every map, and the estimate.
    """
    feature = apply_encoder(encoder, pixels[None])[0]
    chosen, best = identify(library, feature, opening, max_opening_difference_mm=max_opening_difference_mm)
    query = Query(heightmap=heightmap, mask=mask, feature=feature, opening=opening)

    def branch(index):
        return lambda views, query: localize_query(
            jax.random.key(0), views[index], query, method, settings=settings, search=search,
            points_per_query=points_per_query, max_opening_difference_mm=max_opening_difference_mm)

    estimate = jax.lax.switch(chosen, [branch(i) for i in range(len(views))], views, query)
    return chosen, best, estimate


def _touch_program(model: ShapeModel, coordinate_bias: jax.Array | None, encoder: Encoder, library: MapLibrary,
                   views: tuple[LocalizationMap, ...], image: jax.Array, opening: jax.Array, **options):
    """One touch, image (H, W, 3) uint8 and opening (mm) in; identity, pose and fit out."""
    pixels, heightmap, mask, contact = observe(model, image, coordinate_bias)
    chosen, best, estimate = relocalize(encoder, library, views, pixels, heightmap, mask, opening, **options)
    return chosen, best, contact, estimate


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


def check_live_method(method: str | Method) -> Method:
    """The parsed method, after a ValueError if a live loop cannot run it."""
    method = parse_method(method)
    if method.kind == "random":
        raise ValueError("a live localizer needs a retrieval method (cti, cti-icp-N, ...), not random")
    if method.kind == "belief":
        raise ValueError("the live localizer does not run the belief yet: use tactojax.localize.update_belief "
                         "(see the README, 'The pose belief')")
    return method


def check_frame(image: np.ndarray, opening_mm: float, image_shape: tuple[int, ...]) -> np.ndarray:
    """The frame as an array, after a ValueError naming what is wrong with it or the opening."""
    image = np.asarray(image)
    if image.shape != image_shape or image.dtype != np.uint8:
        raise ValueError(f"the localizer takes {image_shape} uint8 RGB frames, got {image.shape} {image.dtype}")
    if not np.isfinite(opening_mm) or opening_mm <= 0:
        raise ValueError(f"the gripper opening must be a positive number of mm, got {opening_mm}")
    return image


def no_contact(latency_s: float) -> LiveEstimate:
    """The estimate of a frame without contact: none."""
    return LiveEstimate(object_id=None, T_object_sensor=None, confidence=0.0, contact=False, similarity=0.0,
                        identity_margin=0.0, residual_mm=0.0, overlap=0.0, converged=False, latency_s=latency_s)


def fit_confidence(residual_mm, overlap, registered):
    """:attr:`LiveEstimate.confidence` of a fit (numbers or arrays alike)."""
    confidence = overlap * np.exp(-(np.asarray(residual_mm) / CONFIDENT_RESIDUAL_MM) ** 2)
    return np.clip(np.where(registered, confidence, 0.0), 0.0, 1.0)


class Localizer:
    """Identify and localize touches against a fixed set of object maps, at camera rate.

    Built once at start-up (this compiles, typically 10-60 s on a CPU); each call then runs one
    precompiled program. Not thread-safe: give each thread its own.

    Args:
        maps: the object maps (features filled by ``encoder``; all of one sensor).
        model: the shape model of the sensor.
        encoder: the feature encoder the maps were built with.
        method: localization method (see :func:`tactojax.localize.localize`).
        settings, search: ICP and search parameters.
        points_per_query: contact points sampled from a touch for ICP.
        max_opening_difference_mm: CTI's opening filter, mm.
    """

    def __init__(self, maps: Sequence[TactileMap], model: ShapeModel, encoder: Encoder, *,
                 method: str | Method = "cti-icp-5", settings: IcpSettings = IcpSettings(),
                 search: SearchSettings = SearchSettings(), points_per_query: int = POINTS_PER_QUERY,
                 max_opening_difference_mm: float = MAX_OPENING_DIFFERENCE_MM):
        maps = check_maps(maps, model, encoder)
        self.method = check_live_method(method)
        self.object_ids = tuple(m.object_id for m in maps)
        self.image_shape = (*model.image_shape, 3)
        # The shape model's per-pixel constant, computed once here rather than in every touch.
        self._operands = (model, jax.jit(coordinate_bias)(model), encoder, MapLibrary.from_maps(maps),
                          tuple(LocalizationMap.from_tactile_map(m) for m in maps))
        program = functools.partial(
            _touch_program, method=self.method, settings=settings, search=search,
            points_per_query=points_per_query, max_opening_difference_mm=max_opening_difference_mm)
        start = time.perf_counter()
        example = (jax.ShapeDtypeStruct(self.image_shape, jnp.uint8), jax.ShapeDtypeStruct((), jnp.float32))
        self._compiled = jax.jit(program).lower(*self._operands, *example).compile()
        self.compile_s = time.perf_counter() - start
        """Seconds spent compiling at start-up."""
        self.kernels = kernel_count(self._compiled)
        """Kernels one touch launches (:func:`tactojax._compilation.kernel_count`)."""

    def __call__(self, image: np.ndarray, opening_mm: float) -> LiveEstimate:
        """Identify and localize one touch.

        Args:
            image: (H, W, 3) uint8 RGB frame of the sensor (rectified, the shape model's size).
            opening_mm: gripper opening at the frame, mm.
        """
        start = time.perf_counter()
        image = check_frame(image, opening_mm, self.image_shape)
        chosen, best, contact, estimate = jax.device_get(
            self._compiled(*self._operands, image, np.float32(opening_mm)))
        return self._summarise(int(chosen), np.asarray(best), bool(contact), estimate,
                               time.perf_counter() - start)

    def _summarise(self, chosen: int, best: np.ndarray, contact: bool, estimate: PoseEstimate,
                   latency_s: float) -> LiveEstimate:
        if not contact:
            return no_contact(latency_s)
        others = np.delete(best, chosen)
        finite_others = others[np.isfinite(others)]
        similarity = float(best[chosen]) if np.isfinite(best[chosen]) else -1.0
        margin = 1.0 if finite_others.size == 0 else similarity - float(finite_others.max())
        converged = bool(estimate.converged)
        residual, overlap = float(estimate.score), float(estimate.overlap)
        confidence = fit_confidence(residual, overlap, int(estimate.imprint_index) >= 0)
        return LiveEstimate(
            object_id=self.object_ids[chosen],
            T_object_sensor=jaxlie.SE3(np.asarray(estimate.T_object_sensor.wxyz_xyz)),
            confidence=float(np.clip(confidence, 0.0, 1.0)), contact=True, similarity=similarity,
            identity_margin=float(margin), residual_mm=residual, overlap=overlap, converged=converged,
            latency_s=latency_s)
