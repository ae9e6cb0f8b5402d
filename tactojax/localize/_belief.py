"""A belief over the object's pose, from one touch or fused over many (beyond the paper).

One update, as a pipeline of small named steps (KISS-ICP style):

1. **remember** the touch: its evidence joins a fixed-size buffer, with its sensor pose relative
   to the belief's *reference* touch (the first one) from the robot's kinematics: several touches
   of an object that stays put, or both fingers of one grasp;
2. **candidates**: the touch's most similar stored imprints (retrieval, CTI's metric and
   opening filter) each spawn a dense grid of poses (:class:`CandidateGrid`), scored by the
   touch's geometric likelihood against the whole map's surface with a coarse noise model; the
   best become hypotheses for the reference touch's pose, pooled with the belief's own (so a
   mode an earlier touch missed can still appear);
3. **weigh**: every pooled hypothesis scores the likelihood of all buffered touches
   (:func:`touch_terms`: geometry, contact and no-contact, against the map's
   signed-distance surface, plus appearance, the touch's embedding similarity to the stored
   imprints where it lands), scaled by the belief's :class:`BeliefCalibration`;
4. **refine**: the ``refine`` best are registered by ICP, all buffered touches at once (their
   points in the reference frame, each against the imprints around where it lands, facing its
   way), and weighed again;
5. **probe** the best hypothesis's neighbourhood (:func:`neighbourhood_probes`): poses just
   outside the 2 mm ball, along the directions the contact pins down least, are weighed too, so
   that a mode free to slide (a patch on a flat face) keeps its spread instead of reporting
   certainty; duplicates are merged and the best ``hypotheses`` kept, normalised.

A symmetric object's copies are all kept (they are distinct poses that the touches cannot tell
apart); :meth:`PoseBelief.probability_within` and :meth:`PoseBelief.modes` treat them as one.

Everything has fixed shapes (``max_touches`` slots, ``hypotheses`` poses), so an update jits
once per map size and settings, and a belief is a pytree that a control loop carries.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Bool, Float, Int

from tactojax import _struct as struct
from tactojax.geometry import take
from tactojax.localize._candidates import CandidateGrid
from tactojax.localize._compile import top_level_jit
from tactojax.localize._correspondences import valid_centroid
from tactojax.localize._evaluate import closest_copy_square, cloud_moments, moment_rmse
from tactojax.localize._icp import IcpSettings, icp
from tactojax.localize._likelihood import LikelihoodSettings, align_depth, log_likelihood
from tactojax.localize._map import BeliefCalibration, LocalizationMap, Touch
from tactojax.localize._points import FREE_BAND_MM, TouchEvidence, touch_evidence
from tactojax.localize._retrieval import rank_imprints

Tree = TypeVar("Tree")

WITHIN_MM = 2.0
"""The error a belief's confidence is about: P(the best pose is within this), mm."""


@dataclass(frozen=True)
class BeliefSettings:
    """Parameters of the belief update (static)."""

    sources: int = 50
    """Retrieved imprints whose neighbourhoods are searched for a new touch."""
    grid: CandidateGrid = CandidateGrid()
    """Offsets tried around every source imprint."""
    screen_points: int = 16
    """Contact and no-contact points each that screen all ``sources x grid.size`` candidates."""
    screened: int = 256
    """Best screened candidates scored with all the touch's points."""
    new_hypotheses: int = 24
    """Best coarse candidates of a new touch that join the pool."""
    registered_sources: int = 8
    """The most similar sources whose poses also start an ICP of the new touch against the
    ``registration_union`` most similar imprints (the paper's CTI-ICP, from several starts):
    their results join the pool too, so that a pose retrieval and registration find is never
    missed by the grid (0: none)."""
    registration_union: int = 5
    """Imprints (the most similar) those registrations fit the touch against."""
    hypotheses: int = 64
    """Hypotheses a belief keeps (every symmetric copy and look-alike mode needs its own)."""
    max_touches: int = 6
    """Touches a belief remembers (e.g. 3 grasps x 2 fingers); older ones are forgotten."""
    contact_points: int = 64
    """Contact points of each touch that the likelihood reads."""
    free_points: int = 64
    """No-contact points of each touch's gel plane that the likelihood reads."""
    free_band_mm: float = FREE_BAND_MM
    """They are drawn first within this distance of the touch's contact, mm
    (:data:`~tactojax.localize._points.FREE_BAND_MM`; 0: uniformly over the gel)."""
    refine: int = 32
    """Hypotheses of the pool (the best by likelihood) that ICP refines (16 left a hypothesis
    within 2 mm of the truth unrefined in a fifth of the marker's failures)."""
    neighbours: int = 4
    """Stored imprints around where a touch lands, facing its way: ICP registers it against
    them, and its appearance is compared with theirs."""
    registration_points: int = 32
    """Contact points of each touch that ICP registers."""
    duplicate_mm: float = 0.5
    """Hypotheses closer than this (the touches' cloud RMSE, not up to symmetry) are one."""
    probe_mm: float = 3.0
    """The best hypothesis's neighbourhood is probed this far away (the touches' cloud RMSE),
    both ways along each of its six principal directions of motion (:func:`neighbourhood_probes`),
    just outside the :data:`WITHIN_MM` ball: a mode that the touches do not pin down (a patch on
    a flat face, free to slide) then holds its spread, and P(within 2 mm) says so (0: no probes)."""
    coarse: LikelihoodSettings = LikelihoodSettings(sigma_mm=0.5, margin_mm=0.5, interpolate=False)
    """Noise model of the unrefined candidates (wider: they sit up to half a grid step off; the
    surface read at the nearest cell)."""
    likelihood: LikelihoodSettings = LikelihoodSettings()
    """Noise model of the refined hypotheses."""
    icp: IcpSettings = IcpSettings()
    """Refinement."""
    max_opening_difference_mm: float = math.inf
    """Retrieval's opening filter, mm. None by default: the opening of a grasp changes by
    several mm with a few degrees of yaw on a tapered or oblique section (the paper's 2 mm
    filter drops every source near the truth on a quarter of the marker's new grasps), and the
    geometry already holds what the opening says (both fingers' gel planes, in the kinematics)."""


@struct.dataclass
class PoseBelief:
    """Weighted hypotheses of the pose of one object, from the touches it remembers.

    The hypotheses are poses of the *reference* touch's sensor (the first touch) in the object
    (map) frame; touch ``t`` then sits at ``T_object_reference @ T_reference_touch[t]``.
    """

    T_object_reference: jaxlie.SE3
    """(M,) hypotheses: the reference sensor's pose in the object frame, mm."""
    log_weights: Float[Array, "M"]
    """Normalised log-probabilities (-inf: an empty slot)."""
    evidence: TouchEvidence
    """(T,) the remembered touches (slot 0: the reference)."""
    features: Float[Array, "T F"]
    """Their unit retrieval features."""
    contact_mm2: Float[Array, "T"]
    """Their contact areas (the observed contact mask), mm²: how often the search misses the
    truth depends on it (:meth:`BeliefCalibration.found_probability`)."""
    T_reference_touch: jaxlie.SE3
    """(T,) every remembered touch's sensor pose in the reference sensor frame, mm."""
    T_world_reference: jaxlie.SE3
    """The reference touch's sensor pose in the world (robot) frame, mm, as the touch came with
    it (identity before any touch)."""
    touch_valid: Bool[Array, "T"]
    """Which slots hold a touch."""
    symmetries: jaxlie.SE3
    """(S,) the object's symmetric copies modulo turns about ``symmetry_axis`` (identity first;
    :attr:`LocalizationMap.symmetries`)."""
    symmetry_axis: Float[Array, "3"]
    """Unit axis of the object's continuous rotational symmetry, object frame (zeros for none)."""
    symmetry_centre: Float[Array, "3"]
    """A point on that axis, object frame, mm."""
    calibration: BeliefCalibration
    """The likelihood's scales."""
    log_evidence: Float[Array, ""]
    """log of the summed (unnormalised) likelihoods of the hypotheses: how well this map
    explains the touches (-inf before any). Comparable between maps whose beliefs share one
    calibration: P(object) is their softmax (:func:`~tactojax.localize.evaluation.identify_episodes`)."""

    @property
    def probabilities(self) -> Float[Array, "M"]:
        """(M,) probabilities of the hypotheses (0 for empty slots)."""
        return jnp.exp(self.log_weights)

    @property
    def best(self) -> jaxlie.SE3:
        """The most likely pose of the reference sensor."""
        return take(self.T_object_reference, jnp.argmax(self.log_weights))

    @property
    def T_world_object(self) -> jaxlie.SE3:
        """The object's most likely pose in the world (robot) frame, mm."""
        return self.T_world_reference @ self.best.inverse()

    def sensor_pose(self, T_world_sensor: jaxlie.SE3) -> jaxlie.SE3:
        """The most likely pose, in the object frame, of a sensor at ``T_world_sensor`` (the
        object staying put)."""
        return self.best @ self.T_world_reference.inverse() @ T_world_sensor

    def touch_pose(self, touch: int | Int[Array, ""] = 0) -> jaxlie.SE3:
        """The most likely pose of remembered touch ``touch``'s sensor in the object frame."""
        return self.best @ take(self.T_reference_touch, touch)

    @property
    def touches(self) -> Int[Array, ""]:
        """How many touches the belief holds."""
        return jnp.sum(self.touch_valid)

    @property
    def has_estimate(self) -> Bool[Array, ""]:
        """Whether it holds any hypothesis (False until a touch felt contact: :attr:`best` is then a
        placeholder, the identity)."""
        return jnp.any(jnp.isfinite(self.log_weights))

    # The queries below are jitted (one program each, not dozens of dispatched operations: a
    # notebook's call takes a fraction of a millisecond once compiled); inside jit they inline.

    @property
    def mean_contact_mm2(self) -> Float[Array, ""]:
        """The mean contact area of the touches the belief holds, mm² (0 before any)."""
        return jnp.sum(jnp.where(self.touch_valid, self.contact_mm2, 0.0)) / jnp.maximum(self.touches, 1)

    def probability_within(self, threshold_mm: float = WITHIN_MM) -> Float[Array, ""]:
        """P(the best pose is within ``threshold_mm`` of the truth, up to the object's
        symmetry), the cloud RMSE of the remembered touches' contact points (the paper's
        metric): the hypotheses' mass near the best, times the probability that they hold the
        truth's mode at all, given how many touches it holds and their contact area
        (:meth:`BeliefCalibration.found_probability`)."""
        return _probability_within(self, threshold_mm)

    def found_probability(self, more_touches: int = 0) -> Float[Array, ""]:
        """P(its hypotheses hold the truth's mode at all), given how many touches it holds and
        their mean contact area (:meth:`BeliefCalibration.found_probability`); with
        ``more_touches``, once that many more of the same area have joined them."""
        return self.calibration.found_probability(self.touches + more_touches, self.mean_contact_mm2)

    def modes(self, separation_mm: float = WITHIN_MM) -> tuple[Int[Array, "M"], Float[Array, "M"]]:
        """Hypotheses grouped into modes (symmetric copies in one): each joins the most likely
        hypothesis within ``separation_mm`` of it. Returns (M,) the mode (a hypothesis index)
        of every hypothesis and (M,) the probability of each mode at its own index (0 elsewhere)."""
        return _modes(self, separation_mm)

    def credible_set(self, level: float = 0.9, separation_mm: float = WITHIN_MM) -> Bool[Array, "M"]:
        """(M,) the hypotheses of the most likely modes that together hold at least ``level`` of
        the probability (the belief's ``level`` credible set of poses)."""
        return _credible_set(self, level, separation_mm)

    def truth_scores(self, T_object_reference: jaxlie.SE3) -> tuple[Float[Array, ""], Bool[Array, ""]]:
        """How the belief scores a known true pose (evaluation): the negative log of its mass
        within 2 mm of it, up to symmetry (floored at 1e-6), and whether the 90 % credible
        set holds a hypothesis within 2 mm of it."""
        return _truth_scores(self, T_object_reference)


@top_level_jit
def _probability_within(belief: PoseBelief, threshold_mm: Float[Array, ""]) -> Float[Array, ""]:
    distance = hypothesis_distances(belief, belief.best, symmetric=True)
    near = jnp.sum(jnp.where(distance <= threshold_mm, belief.probabilities, 0.0))
    return near * belief.found_probability()


@top_level_jit
def _modes(belief: PoseBelief, separation_mm: Float[Array, ""]) -> tuple[Int[Array, "M"], Float[Array, "M"]]:
    order = jnp.argsort(-belief.log_weights)
    poses = take(belief.T_object_reference, order)
    distance = jax.vmap(lambda T: hypothesis_distances(belief, T, symmetric=True))(poses)[:, order]  # sorted
    near = (distance <= separation_mm) & jnp.isfinite(belief.log_weights[order])[None, :]
    # Each hypothesis joins the first (most likely) one near it.
    mode = order[jnp.argmax(near, axis=1)]
    mode = jnp.zeros_like(order).at[order].set(mode)
    mass = jnp.zeros_like(belief.log_weights).at[mode].add(belief.probabilities)
    return mode, mass


@top_level_jit
def _credible_set(belief: PoseBelief, level: Float[Array, ""], separation_mm: Float[Array, ""]) -> Bool[Array, "M"]:
    mode, mass = _modes(belief, separation_mm)
    order = jnp.argsort(-mass)
    before = jnp.cumsum(mass[order]) - mass[order]
    chosen = jnp.zeros(mass.shape, bool).at[order].set((before < level) & (mass[order] > 0))
    return chosen[mode] & jnp.isfinite(belief.log_weights)


@top_level_jit
def _truth_scores(belief: PoseBelief, T_object_reference: jaxlie.SE3) -> tuple[Float[Array, ""], Bool[Array, ""]]:
    near = hypothesis_distances(belief, T_object_reference, symmetric=True) <= WITHIN_MM
    mass = jnp.sum(jnp.where(near, belief.probabilities, 0.0))
    return -jnp.log(jnp.maximum(mass, 1e-6)), jnp.any(near & _credible_set(belief, 0.9, WITHIN_MM))


@struct.dataclass
class BeliefDigest:
    """What a belief reports, as arrays (:func:`belief_digest`): the live loop's estimate and the
    commands' output."""

    T_world_object: Float[Array, "7"]
    """The object's most likely pose in the world frame (wxyz_xyz, mm)."""
    T_object_sensor: Float[Array, "7"]
    """The first touch's sensor in the object frame, at the most likely pose."""
    probability_within: Float[Array, ""]
    """P(the best pose is within 2 mm), up to the object's symmetry."""
    touches: Int[Array, ""]
    """Touches the belief holds."""
    log_evidence: Float[Array, ""]
    """:attr:`PoseBelief.log_evidence`."""
    mode_probability: Float[Array, "K"]
    """The K most probable modes' probabilities (0: no such mode)."""
    mode_T_world_object: Float[Array, "K 7"]
    """Their object poses in the world frame."""
    mode_T_object_sensor: Float[Array, "K 7"]
    """Their first-touch sensor poses in the object frame."""


@functools.partial(top_level_jit, static_argnames=("modes",))
def belief_digest(belief: PoseBelief, modes: int = 3) -> BeliefDigest:
    """A belief's estimate, confidence and ``modes`` most probable modes, in one compiled call."""
    _, mass = belief.modes()
    probability, index = jax.lax.top_k(mass, modes)
    T_object_sensor = take(belief.T_object_reference, index)
    return BeliefDigest(T_world_object=belief.T_world_object.wxyz_xyz, T_object_sensor=belief.best.wxyz_xyz,
                        probability_within=belief.probability_within(), touches=belief.touches,
                        log_evidence=belief.log_evidence, mode_probability=probability,
                        mode_T_world_object=(belief.T_world_reference @ T_object_sensor.inverse()).wxyz_xyz,
                        mode_T_object_sensor=T_object_sensor.wxyz_xyz)


def reference_cloud(belief: PoseBelief) -> tuple[Float[Array, "N 3"], Bool[Array, "N"]]:
    """(T * P, 3) the remembered touches' contact points in the reference sensor frame (mm),
    and (T * P,) which are valid (a point of a remembered touch)."""
    points = jax.vmap(lambda T, p: T @ p)(belief.T_reference_touch, belief.evidence.contact)
    valid = belief.evidence.contact_valid & belief.touch_valid[:, None]
    return points.reshape(-1, 3), valid.reshape(-1)


def hypothesis_distances(belief: PoseBelief, T_object_reference: jaxlie.SE3, *,
                         symmetric: bool = False) -> Float[Array, "M"]:
    """(M,) RMSE (mm) between the remembered touches' contact points placed by every hypothesis
    and by ``T_object_reference`` (the paper's metric over the fused touches); with
    ``symmetric``, by its closest symmetric copy: every copy, each also turned to its closest
    about the continuous symmetry axis (:func:`closest_copy_square`, exact)."""
    mean, covariance = cloud_moments(*reference_cloud(belief))
    if not symmetric:
        return moment_rmse(mean, covariance, belief.T_object_reference, T_object_reference)
    one = lambda T: jaxlie.SE3(T.wxyz_xyz[None])  # noqa: E731  (a batch of one cloud's pose)
    square = jax.vmap(lambda T: closest_copy_square(mean[None], covariance[None], jnp.ones(1, bool), one(T),
                                                    one(T_object_reference), belief.symmetries,
                                                    belief.symmetry_axis, belief.symmetry_centre))
    return jnp.sqrt(square(belief.T_object_reference))


def empty_belief(view: LocalizationMap, settings: BeliefSettings = BeliefSettings()) -> PoseBelief:
    """A belief with no touch (every hypothesis slot empty), with the map's symmetries and
    calibration.

    Args:
        view: the object's map.
        settings: the update's parameters (hypothesis and touch slots, points per touch).
    """
    count, slots = settings.hypotheses, settings.max_touches
    contact, free = settings.contact_points, settings.free_points
    evidence = TouchEvidence(contact=jnp.zeros((slots, contact, 3)), contact_valid=jnp.zeros((slots, contact), bool),
                             free=jnp.zeros((slots, free, 3)), free_valid=jnp.zeros((slots, free), bool))
    return PoseBelief(T_object_reference=jaxlie.SE3.identity((count,)),
                      log_weights=jnp.full((count,), -jnp.inf, jnp.float32), evidence=evidence,
                      features=jnp.zeros((slots, view.features.shape[1])), contact_mm2=jnp.zeros((slots,)),
                      T_reference_touch=jaxlie.SE3.identity((slots,)), touch_valid=jnp.zeros((slots,), bool),
                      T_world_reference=jaxlie.SE3.identity(), symmetries=view.symmetries,
                      symmetry_axis=view.symmetry_axis, symmetry_centre=view.symmetry_centre,
                      calibration=view.calibration, log_evidence=jnp.float32(-jnp.inf))


def _unit(feature: Float[Array, "F"]) -> Float[Array, "F"]:
    return feature / jnp.maximum(jnp.linalg.norm(feature), 1e-12)


def remember(belief: PoseBelief, evidence: TouchEvidence, feature: Float[Array, "F"], contact_mm2: Float[Array, ""],
             T_reference_touch: jaxlie.SE3) -> PoseBelief:
    """Step 1: the touch joins the buffer (the oldest non-reference touch goes when it is full)."""
    slots = belief.touch_valid.shape[0]
    full = jnp.all(belief.touch_valid)
    # When full, shift slots 2.. down by one (slot 0 stays the reference) and write the last.
    order = jnp.where(full, jnp.concatenate([jnp.array([0]), jnp.arange(2, slots + 1) % slots]), jnp.arange(slots))
    buffers = (belief.evidence, belief.features, belief.contact_mm2, belief.T_reference_touch.wxyz_xyz,
               belief.touch_valid)
    evidence_buffer, features, areas, poses, valid = take(buffers, order)
    slot = jnp.where(full, slots - 1, jnp.argmin(belief.touch_valid))
    put = lambda old, new: old.at[slot].set(new)  # noqa: E731
    return belief.replace(evidence=jax.tree.map(put, evidence_buffer, evidence), features=put(features, _unit(feature)),
                          contact_mm2=put(areas, contact_mm2),
                          T_reference_touch=jaxlie.SE3(put(poses, T_reference_touch.wxyz_xyz)),
                          touch_valid=put(valid, True))


def facing_imprints(view: LocalizationMap, T_object_sensor: jaxlie.SE3, evidence: TouchEvidence,
                    count: int) -> tuple[Int[Array, "count"], Bool[Array, "count"]]:
    """:meth:`LocalizationMap.imprints_near` where a touch's contact lands."""
    centre = T_object_sensor @ valid_centroid(evidence.contact, evidence.contact_valid)
    return view.imprints_near(T_object_sensor, centre, count)


def facing_imprints_of_touches(view: LocalizationMap, belief: PoseBelief, T_object_reference: jaxlie.SE3,
                               count: int) -> tuple[Int[Array, "T count"], Bool[Array, "T count"]]:
    """:func:`facing_imprints` of every touch the belief holds at one hypothesis (reference
    frame); the empty slots hold none (looked up in a loop over the touches held, as
    :func:`sum_over_touches`)."""
    slots = belief.touch_valid.shape[0]

    def one(t, found):
        nearby, valid = facing_imprints(view, T_object_reference @ take(belief.T_reference_touch, t),
                                        take(belief.evidence, t), count)
        return found[0].at[t].set(nearby), found[1].at[t].set(valid & belief.touch_valid[t])

    return jax.lax.fori_loop(0, belief.touches, one, (jnp.zeros((slots, count), jnp.int32),
                                                       jnp.zeros((slots, count), bool)))


def touch_terms(view: LocalizationMap, evidence: TouchEvidence, feature: Float[Array, "F"],
                T_object_sensor: jaxlie.SE3, settings: BeliefSettings) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """The two cues of one touch at a pose, before calibration: its geometric log-likelihood
    against the map's surface, and the best cosine similarity of its unit features to the stored
    imprints where it lands (0 where none faces its way)."""
    geometry = log_likelihood(view.surface, T_object_sensor, evidence, settings.likelihood)
    nearby, nearby_valid = facing_imprints(view, T_object_sensor, evidence, settings.neighbours)
    similarity = jnp.max(jnp.where(nearby_valid, view.features[nearby] @ feature, -1.0))
    return geometry, jnp.where(jnp.any(nearby_valid), similarity, 0.0)


def belief_terms(view: LocalizationMap, belief: PoseBelief, T_object_reference: jaxlie.SE3,
                 settings: BeliefSettings) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """:func:`touch_terms` summed over the touches a belief holds, at one hypothesis."""
    return sum_over_touches(belief, lambda t: touch_terms(
        view, take(belief.evidence, t), belief.features[t], T_object_reference @ take(belief.T_reference_touch, t),
        settings))


def sum_over_touches(belief: PoseBelief, term: Callable[[Int[Array, ""]], Tree]) -> Tree:
    """``term(t)`` (a pytree of arrays) summed over the touches ``t`` the belief holds.

    A belief's touches fill its first slots (:func:`remember`), so the sum runs over them alone,
    in a loop: an update costs what the touches it holds cost, not what ``max_touches`` slots
    would (vmapped over beliefs, the loop runs to the batch's most touches). Slot 0, the
    reference, counts only when it holds a touch."""
    first = jax.tree.map(lambda x: jnp.where(belief.touch_valid[0], x, jnp.zeros_like(x)), term(jnp.int32(0)))
    return jax.lax.fori_loop(1, belief.touches, lambda t, total: jax.tree.map(jnp.add, total, term(t)), first)


def calibrated_log_likelihood(calibration: BeliefCalibration, geometry: Float[Array, "*M"],
                              similarity: Float[Array, "*M"], touches: Int[Array, ""]) -> Float[Array, "*M"]:
    """The belief's log-likelihood from the summed cues of ``touches`` touches (see
    :class:`BeliefCalibration`)."""
    scale = jnp.maximum(touches, 1).astype(jnp.float32) ** -calibration.fusion_exponent
    return scale * (calibration.temperature * geometry + calibration.appearance * similarity)


def _first_points(evidence: TouchEvidence, count: int) -> TouchEvidence:
    """The evidence's first ``count`` contact and no-contact points: a uniform draw of each,
    as :func:`~tactojax.localize.touch_evidence` orders them (valid points first, at random)."""
    return jax.tree.map(lambda x: x[:count], evidence)


def candidates(view: LocalizationMap, belief: PoseBelief, evidence: TouchEvidence,
               feature: Float[Array, "F"], opening: Float[Array, ""], T_reference_touch: jaxlie.SE3,
               settings: BeliefSettings, exclude: int | Int[Array, ""] = -1) -> tuple[jaxlie.SE3, Float[Array, "C"]]:
    """Step 2: the best ``new_hypotheses`` candidate poses of the reference touch that a new
    touch proposes (object frame), and their coarse log-likelihoods (-inf where retrieval found
    too few imprints).

    Every candidate is scored by the coarse likelihood of *every* touch the belief holds
    (``belief`` already remembers the new one): what the other touches say is the strongest
    evidence a candidate can get (on a long cylinder, a single touch fits hundreds of them
    equally). Coarse to fine: all candidates are first screened with a few points of each
    touch (``screen_points``, one depth alignment step of the new touch, the surface read at
    its nearest cells as the coarse likelihood reads it); the ``screened``
    best are then aligned with all the new touch's points, from their original offsets, and
    scored with all points of every touch.
    """
    sources, _, sources_valid = rank_imprints(
        view.features @ _unit(feature), view.openings, view.imprint_valid, opening, settings.sources,
        max_opening_difference_mm=settings.max_opening_difference_mm, exclude=exclude)
    offsets = settings.grid.offsets(valid_centroid(evidence.contact, evidence.contact_valid))
    few = _first_points(evidence, settings.screen_points)
    few_of_every_touch = jax.tree.map(lambda x: x[:, :settings.screen_points], belief.evidence)
    per_source = settings.grid.size
    surface = view.surface

    def joint(T_object_reference, evidence_):
        return sum_over_touches(belief, lambda t: log_likelihood(
            surface, T_object_reference @ take(belief.T_reference_touch, t), take(evidence_, t), settings.coarse))

    def screen(source, T_source_sensor):
        T = align_depth(surface, take(view.T_object_sensor, source) @ T_source_sensor, few, iterations=1,
                        interpolate=settings.coarse.interpolate)
        return joint(T @ T_reference_touch.inverse(), few_of_every_touch)

    screening = jax.vmap(lambda source: jax.vmap(lambda T: screen(source, T))(offsets))(sources)  # (sources, S)
    screening = jnp.where(sources_valid[:, None], screening, -jnp.inf).reshape(-1)
    kept_scores, kept = jax.lax.top_k(screening, min(settings.screened, screening.shape[0]))
    source = sources[kept // per_source]
    aligned = jax.vmap(lambda s, T: align_depth(surface, take(view.T_object_sensor, s) @ T, evidence))(
        source, take(offsets, kept % per_source))
    T_object_reference = aligned @ T_reference_touch.inverse()
    scores = jax.vmap(lambda T: joint(T, belief.evidence))(T_object_reference)
    scores = jnp.where(jnp.isfinite(kept_scores), scores, -jnp.inf)
    best_scores, best = jax.lax.top_k(scores, settings.new_hypotheses)
    T_best = take(T_object_reference, best)
    if settings.registered_sources == 0:
        return T_best, best_scores
    T_registered = register_sources(view, evidence, sources, sources_valid, settings) @ T_reference_touch.inverse()
    registered_scores = jax.vmap(lambda T: joint(T, belief.evidence))(T_registered)
    registered_scores = jnp.where(sources_valid[:settings.registered_sources], registered_scores, -jnp.inf)
    return (jax.tree.map(lambda a, b: jnp.concatenate([a, b]), T_best, T_registered),
            jnp.concatenate([best_scores, registered_scores]))


def register_sources(view: LocalizationMap, evidence: TouchEvidence, sources: Int[Array, "N"],
                     sources_valid: Bool[Array, "N"], settings: BeliefSettings) -> jaxlie.SE3:
    """(R,) the new touch's sensor pose by ICP from each of the ``registered_sources`` most
    similar sources' poses, against the ``registration_union`` most similar imprints (object frame)."""
    union = settings.registration_union
    starts = take(view.T_object_sensor, sources[:settings.registered_sources])
    register = jax.vmap(lambda T: icp(view, sources[:union], sources_valid[:union], evidence.contact,
                                      evidence.contact_valid, T, settings.icp).T_object_sensor)
    return register(starts)


def refine(view: LocalizationMap, belief: PoseBelief, T_object_reference: jaxlie.SE3,
           settings: BeliefSettings) -> jaxlie.SE3:
    """Step 4: ICP of all remembered touches at once from one hypothesis (reference frame),
    each touch's points against the stored imprints around where it lands."""
    nearby, nearby_valid = facing_imprints_of_touches(view, belief, T_object_reference, settings.neighbours)
    used = settings.registration_points
    candidates_ = jnp.repeat(nearby, used, axis=0)  # (T * used, n)
    candidates_valid = jnp.repeat(nearby_valid, used, axis=0)
    points = jax.vmap(lambda T, p: T @ p)(belief.T_reference_touch, belief.evidence.contact[:, :used])
    points_valid = belief.evidence.contact_valid[:, :used] & belief.touch_valid[:, None]
    # Each touch's points a block: the empty slots are never looked up.
    estimate = icp(view, candidates_, candidates_valid, points.reshape(-1, 3), points_valid.reshape(-1),
                   T_object_reference, settings.icp, blocks=belief.touch_valid.shape[0], active_blocks=belief.touches)
    return estimate.T_object_sensor


def weigh(view: LocalizationMap, belief: PoseBelief, T_object_reference: jaxlie.SE3,
          settings: BeliefSettings) -> Float[Array, ""]:
    """Step 3: the calibrated log-likelihood of all remembered touches at one hypothesis."""
    geometry, similarity = belief_terms(view, belief, T_object_reference, settings)
    return calibrated_log_likelihood(belief.calibration, geometry, similarity, belief.touches)


@functools.partial(top_level_jit, static_argnames=("settings",))
def truth_against_best(view: LocalizationMap, belief: PoseBelief, T_object_reference: jaxlie.SE3,
                       settings: BeliefSettings = BeliefSettings()) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """Why a belief is wrong (evaluation): its calibrated log-likelihood of all its touches at its
    best hypothesis, and at the true pose ``T_object_reference`` (the reference sensor's, object
    frame, mm) refined by the belief's own ICP (the better of the truth and its refinement). The
    truth scoring higher: the search never reached it; lower: the likelihood prefers a wrong pose
    (the touches, as the map explains them, do not tell them apart)."""
    refined = refine(view, belief, T_object_reference, settings)
    truth = jnp.maximum(weigh(view, belief, T_object_reference, settings), weigh(view, belief, refined, settings))
    return weigh(view, belief, belief.best, settings), truth


def _keep_distinct(belief: PoseBelief, poses: jaxlie.SE3, scores: Float[Array, "N"], count: int,
                   duplicate_mm: float) -> tuple[jaxlie.SE3, Float[Array, "count"]]:
    """The ``count`` best poses, a pose within ``duplicate_mm`` of a better one dropped."""
    order = jnp.argsort(-scores)
    poses, scores = take(poses, order), scores[order]
    probe = belief.replace(T_object_reference=poses)
    distance = jax.vmap(lambda T: hypothesis_distances(probe, T))(poses)  # (N, N)
    earlier = jnp.tril(jnp.ones_like(distance, bool), k=-1)  # [i, j]: j is better than i
    duplicate = jnp.any(earlier & (distance <= duplicate_mm) & jnp.isfinite(scores)[None, :], axis=1)
    scores = jnp.where(duplicate, -jnp.inf, scores)
    best_scores, best = jax.lax.top_k(scores, count)
    return take(poses, best), best_scores


def neighbourhood_probes(view: LocalizationMap, belief: PoseBelief, T_object_reference: jaxlie.SE3,
                         distance_mm: float, max_turn_rad: float = 1.0) -> jaxlie.SE3:
    """(12,) poses about ``distance_mm`` (the cloud RMSE of the belief's touches, to first order)
    from the hypothesis ``T_object_reference``, both ways along each principal direction of what
    the touches' contact says about the pose.

    The directions are the generalised eigenvectors of the contact points' Gauss-Newton
    information (``J^T J``, ``J`` the (P, 6) derivative of their signed distances to the map's
    surface by a motion of the reference frame) against the cloud-RMSE metric (``K^T K``, ``K``
    the derivative of the points themselves): on a flat face they span the slides and the turn
    in the face, which the contact cannot see; on a cylinder, the slide along and the turn
    about its axis. A turn larger than ``max_turn_rad`` is shortened to it (a pinpoint contact).
    """
    points, valid = reference_cloud(belief)
    count = jnp.maximum(jnp.sum(valid), 1).astype(jnp.float32)
    zero = jnp.zeros(6)

    def moved(delta):  # (P, 3) the points in the reference frame after the motion exp(delta)
        return jnp.where(valid[:, None], jaxlie.SE3.exp(delta) @ points, 0.0)

    def distances(delta):
        distance, known = view.surface.signed_distance(T_object_reference @ moved(delta))
        return jnp.where(valid & known, distance, 0.0)

    J = jax.jacfwd(distances)(zero)  # (P, 6)
    K = jax.jacfwd(moved)(zero)  # (P, 3, 6)
    information = J.T @ J / count
    metric = jnp.einsum("pik,pil->kl", K, K) / count + 1e-6 * jnp.eye(6)
    lower = jnp.linalg.cholesky(metric)
    whiten = jax.scipy.linalg.solve_triangular(lower, jnp.eye(6), lower=True)  # L^-1
    _, eigenvectors = jnp.linalg.eigh(whiten @ information @ whiten.T)
    directions = (whiten.T @ eigenvectors).T  # (6, 6) rows u with u^T metric u = 1
    deltas = distance_mm * jnp.concatenate([directions, -directions])  # (12, 6): (translation, rotation)
    turn = jnp.linalg.norm(deltas[:, 3:], axis=1, keepdims=True)
    deltas = deltas * jnp.minimum(1.0, max_turn_rad / jnp.maximum(turn, 1e-9))
    return jax.vmap(lambda delta: T_object_reference @ jaxlie.SE3.exp(delta))(deltas)


def update_belief(
    view: LocalizationMap,
    belief: PoseBelief,
    touch: Touch,
    T_world_sensor: jaxlie.SE3,
    settings: BeliefSettings = BeliefSettings(),
    *,
    exclude: int | Int[Array, ""] = -1,
) -> PoseBelief:
    """``belief`` after one more touch (see the module docstring). Pure; vmap and jit freely.

    Args:
        view: the object's map (:meth:`LocalizationMap.from_tactile_map`).
        belief: the belief so far (:func:`empty_belief` before the first touch).
        touch: the new touch.
        T_world_sensor: its sensor's pose in any fixed frame in which the object stays put (the
            robot's base: gripper pose and finger kinematics), mm. Only the poses of a belief's
            touches relative to each other matter; the first touch's becomes the reference.
        settings: parameters (static).
        exclude: a map imprint never used as a source (leave-one-out), -1 for none.

    Returns:
        the updated belief (never NaN); a touch without contact changes nothing (before any
        touch with contact, every hypothesis slot stays empty: no estimate).
    """
    evidence = touch_evidence(touch, view.mm_per_px, contact_count=settings.contact_points,
                              free_count=settings.free_points, free_band_mm=settings.free_band_mm)
    feature, opening = touch.feature, touch.opening
    before = belief
    first = ~jnp.any(belief.touch_valid)
    T_world_reference = jax.tree.map(lambda new, old: jnp.where(first, new, old), T_world_sensor,
                                     belief.T_world_reference)
    # The reference touch sits at the identity exactly (not up to float32 rounding of T^-1 T).
    T_reference_touch = jax.tree.map(lambda identity, relative: jnp.where(first, identity, relative),
                                     jaxlie.SE3.identity(), T_world_reference.inverse() @ T_world_sensor)
    belief = belief.replace(T_world_reference=T_world_reference)
    contact_mm2 = jnp.sum(touch.mask) * view.mm_per_px ** 2
    belief = remember(belief, evidence, feature, contact_mm2, T_reference_touch)
    T_new, new_scores = candidates(view, belief, evidence, feature, opening, T_reference_touch, settings, exclude)
    old_valid = jnp.isfinite(belief.log_weights) & ~first
    pooled = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), belief.T_object_reference, T_new)
    pooled_valid = jnp.concatenate([old_valid, jnp.isfinite(new_scores)])
    score = jax.vmap(lambda T: weigh(view, belief, T, settings))
    scores = jnp.where(pooled_valid, score(pooled), -jnp.inf)
    _, chosen = jax.lax.top_k(scores, settings.refine)
    refined = jax.vmap(lambda T: refine(view, belief, T, settings))(take(pooled, chosen))
    refined_scores = jnp.where(jnp.isfinite(scores[chosen]), score(refined), -jnp.inf)
    # A refinement that fits worse than its start keeps the start.
    better = refined_scores >= scores[chosen]
    pooled = jax.tree.map(lambda x, r: x.at[chosen].set(jnp.where(better[:, None], r, x[chosen])), pooled,
                          refined)
    scores = scores.at[chosen].set(jnp.maximum(refined_scores, scores[chosen]))
    scores = jnp.where(jnp.isfinite(scores), scores, -jnp.inf)
    if settings.probe_mm > 0:
        probes = neighbourhood_probes(view, belief, take(pooled, jnp.argmax(scores)), settings.probe_mm)
        probe_scores = jnp.where(jnp.any(jnp.isfinite(scores)), score(probes), -jnp.inf)
        pooled = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), pooled, probes)
        scores = jnp.concatenate([scores, jnp.where(jnp.isfinite(probe_scores), probe_scores, -jnp.inf)])
    poses, kept = _keep_distinct(belief, pooled, scores, settings.hypotheses, settings.duplicate_mm)
    any_valid = jnp.any(jnp.isfinite(kept))
    log_evidence = jax.nn.logsumexp(jnp.where(any_valid, kept, 0.0))
    log_weights = kept - log_evidence
    log_weights = jnp.where(any_valid & jnp.isfinite(kept), log_weights, -jnp.inf)
    poses = jaxlie.SE3(jnp.where(jnp.isfinite(poses.wxyz_xyz), poses.wxyz_xyz, jaxlie.SE3.identity().wxyz_xyz))
    after = belief.replace(T_object_reference=poses, log_weights=log_weights,
                           log_evidence=jnp.where(any_valid, log_evidence, -jnp.inf))
    contact = jnp.any(evidence.contact_valid)
    return jax.tree.map(lambda new, old: jnp.where(contact, new, old), after, before)
