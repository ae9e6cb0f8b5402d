"""A belief over the object's pose, from one touch or fused over many (beyond the paper).

One update, as a pipeline of small named steps (KISS-ICP style):

1. **remember** the touch: its evidence joins a fixed-size buffer, with its sensor pose relative
   to the belief's *reference* touch (the first one) from the robot's kinematics: several touches
   of an object that stays put, or both fingers of one grasp;
2. **candidates**: the touch's most similar stored imprints (retrieval, CTI's metric and
   opening filter) each spawn a dense grid of poses (:class:`CandidateGrid`), scored by the
   touch's likelihood in the source imprint's local view with a coarse noise model; the best
   become hypotheses for the reference touch's pose, pooled with the belief's own;
3. **refine**: every pooled hypothesis is registered by ICP, all buffered touches at once (their
   points in the reference frame, each against the imprints around where it lands, facing its
   way);
4. **weigh**: each refined hypothesis scores the sum over buffered touches of their likelihoods
   (contact and no-contact, :mod:`tactojax.localize._likelihood`) in the view nearest to where
   the touch lands; duplicates are merged and the best ``hypotheses`` kept, normalised.

Everything has fixed shapes (``max_touches`` slots, ``hypotheses`` poses), so an update jits
once per map size and settings, and a belief is a pytree that a control loop carries.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
from flax import struct
from jaxtyping import Array, Bool, Float, Int

from tactojax.localize._candidates import CandidateGrid
from tactojax.localize._correspondences import valid_centroid
from tactojax.localize._evaluate import cloud_moments, moment_rmse
from tactojax.localize._icp import IcpSettings, icp
from tactojax.localize._likelihood import LikelihoodSettings, TouchEvidence, align_depth, log_likelihood
from tactojax.localize._map import LocalizationMap
from tactojax.localize._retrieval import MAX_OPENING_DIFFERENCE_MM, rank_imprints
from tactojax.localize._views import SurfaceViews

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
    hypotheses: int = 16
    """Hypotheses a belief keeps."""
    max_touches: int = 6
    """Touches a belief remembers (e.g. 3 grasps x 2 fingers); older ones are forgotten."""
    refine: int = 16
    """Hypotheses of the pool (the best by likelihood) that ICP refines."""
    registration_neighbours: int = 4
    """Imprints around each touch's landing place that ICP registers it against."""
    registration_points: int = 32
    """Contact points of each touch that ICP registers."""
    duplicate_mm: float = 0.5
    """Hypotheses closer than this (the reference touch's cloud RMSE) are one."""
    coarse: LikelihoodSettings = LikelihoodSettings(sigma_mm=0.5, margin_mm=0.5)
    """Noise model of the unrefined candidates (wider: they sit up to half a grid step off)."""
    likelihood: LikelihoodSettings = LikelihoodSettings()
    """Noise model of the refined hypotheses."""
    icp: IcpSettings = IcpSettings()
    """Refinement."""
    max_opening_difference_mm: float = MAX_OPENING_DIFFERENCE_MM
    """Retrieval's opening filter, mm."""


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
    T_reference_touch: jaxlie.SE3
    """(T,) every remembered touch's sensor pose in the reference sensor frame, mm."""
    touch_valid: Bool[Array, "T"]
    """Which slots hold a touch."""

    @property
    def probabilities(self) -> Float[Array, "M"]:
        """(M,) probabilities of the hypotheses (0 for empty slots)."""
        return jnp.exp(self.log_weights)

    @property
    def best(self) -> jaxlie.SE3:
        """The most likely pose of the reference sensor."""
        return jax.tree.map(lambda x: x[jnp.argmax(self.log_weights)], self.T_object_reference)

    def touch_pose(self, touch: int | Int[Array, ""] = 0) -> jaxlie.SE3:
        """The most likely pose of remembered touch ``touch``'s sensor in the object frame."""
        return self.best @ jax.tree.map(lambda x: x[touch], self.T_reference_touch)

    @property
    def touches(self) -> Int[Array, ""]:
        """How many touches the belief holds."""
        return jnp.sum(self.touch_valid)

    def probability_within(self, threshold_mm: float = WITHIN_MM) -> Float[Array, ""]:
        """P(the best pose is within ``threshold_mm`` of the truth), the cloud RMSE of the
        remembered touches' contact points (the paper's metric), under the belief."""
        distance = hypothesis_distances(self, self.best)
        return jnp.sum(jnp.where(distance <= threshold_mm, self.probabilities, 0.0))

    def modes(self, separation_mm: float = WITHIN_MM) -> tuple[Int[Array, "M"], Float[Array, "M"]]:
        """Hypotheses grouped into modes: each joins the most likely hypothesis within
        ``separation_mm`` of it. Returns (M,) the mode (a hypothesis index) of every hypothesis
        and (M,) the probability of each mode at its own index (0 elsewhere)."""
        order = jnp.argsort(-self.log_weights)
        poses = jax.tree.map(lambda x: x[order], self.T_object_reference)
        distance = jax.vmap(lambda T: hypothesis_distances(self, T))(poses)[:, order]  # (M, M) sorted
        near = (distance <= separation_mm) & jnp.isfinite(self.log_weights[order])[None, :]
        # Each hypothesis joins the first (most likely) one near it.
        mode_sorted = jnp.argmax(near, axis=1)
        mode = order[mode_sorted]
        mode = jnp.zeros_like(order).at[order].set(mode)
        mass = jnp.zeros_like(self.log_weights).at[mode].add(self.probabilities)
        return mode, mass


def hypothesis_distances(belief: PoseBelief, T_object_reference: jaxlie.SE3) -> Float[Array, "M"]:
    """(M,) RMSE (mm) between the remembered touches' contact points placed by every hypothesis
    and by ``T_object_reference`` (the paper's metric over the fused touches)."""
    points = jax.vmap(lambda T, p: T @ p)(belief.T_reference_touch, belief.evidence.contact)  # reference frame
    valid = belief.evidence.contact_valid & belief.touch_valid[:, None]
    mean, covariance = cloud_moments(points.reshape(-1, 3), valid.reshape(-1))
    return moment_rmse(mean, covariance, belief.T_object_reference, T_object_reference)


def empty_belief(settings: BeliefSettings, contact_points: int, free_points: int) -> PoseBelief:
    """A belief with no touch (every hypothesis slot empty)."""
    count, slots = settings.hypotheses, settings.max_touches
    evidence = TouchEvidence(contact=jnp.zeros((slots, contact_points, 3)),
                             contact_valid=jnp.zeros((slots, contact_points), bool),
                             free=jnp.zeros((slots, free_points, 3)), free_valid=jnp.zeros((slots, free_points), bool))
    return PoseBelief(T_object_reference=jaxlie.SE3.identity((count,)),
                      log_weights=jnp.full((count,), -jnp.inf), evidence=evidence,
                      T_reference_touch=jaxlie.SE3.identity((slots,)), touch_valid=jnp.zeros((slots,), bool))


def _take(tree, index):
    return jax.tree.map(lambda x: x[index], tree)


def remember(belief: PoseBelief, evidence: TouchEvidence, T_reference_touch: jaxlie.SE3) -> PoseBelief:
    """Step 1: the touch joins the buffer (the oldest non-reference touch goes when it is full)."""
    slots = belief.touch_valid.shape[0]
    full = jnp.all(belief.touch_valid)
    # When full, shift slots 2.. down by one (slot 0 stays the reference) and write the last.
    order = jnp.where(full, jnp.concatenate([jnp.array([0]), jnp.arange(2, slots + 1) % slots]), jnp.arange(slots))
    shifted = jax.tree.map(lambda x: x[order], (belief.evidence, belief.T_reference_touch.wxyz_xyz, belief.touch_valid))
    slot = jnp.where(full, slots - 1, jnp.argmin(belief.touch_valid))
    put = lambda old, new: old.at[slot].set(new)  # noqa: E731
    evidence_buffer = jax.tree.map(put, shifted[0], evidence)
    poses = put(shifted[1], T_reference_touch.wxyz_xyz)
    return belief.replace(evidence=evidence_buffer, T_reference_touch=jaxlie.SE3(poses),
                          touch_valid=put(shifted[2], True))


def nearest_view(view: LocalizationMap, T_object_sensor: jaxlie.SE3, evidence: TouchEvidence) -> Int[Array, ""]:
    """The stored imprint facing the touch's way whose contact centre is nearest to the touch's."""
    centre = T_object_sensor @ valid_centroid(evidence.contact, evidence.contact_valid)
    normal = T_object_sensor.rotation() @ jnp.array([0.0, 0.0, 1.0])
    normals = view.T_object_sensor.rotation().as_matrix()[..., :, 2]
    distance = jnp.linalg.norm(view.centres - centre, axis=-1)
    ok = view.imprint_valid & (normals @ normal >= 0.5)
    return jnp.argmin(jnp.where(ok, distance, jnp.inf))


def touch_log_likelihood(view: LocalizationMap, views: SurfaceViews, evidence: TouchEvidence,
                         T_object_sensor: jaxlie.SE3, settings: LikelihoodSettings) -> Float[Array, ""]:
    """One touch's log-likelihood at a pose, in the view nearest to where it lands."""
    index = nearest_view(view, T_object_sensor, evidence)
    return log_likelihood(views, index, _take(view.T_object_sensor, index).inverse() @ T_object_sensor, evidence,
                          settings)


def _first_points(evidence: TouchEvidence, count: int) -> TouchEvidence:
    """The evidence's first ``count`` contact and no-contact points: a uniform draw of each,
    as :func:`~tactojax.localize.touch_evidence` orders them (valid points first, at random)."""
    return jax.tree.map(lambda x: x[:count], evidence)


def candidates(view: LocalizationMap, views: SurfaceViews, evidence: TouchEvidence, feature: Float[Array, "F"],
               opening: Float[Array, ""], settings: BeliefSettings,
               exclude: int | Int[Array, ""] = -1) -> tuple[jaxlie.SE3, Float[Array, "C"]]:
    """Step 2: the best ``new_hypotheses`` candidate poses of one touch (object frame) and
    their coarse log-likelihoods (-inf where retrieval found too few imprints).

    Coarse to fine: every candidate of every source is first screened with a few of the
    touch's points (``screen_points``, one depth alignment step); the ``screened`` best are
    then aligned and scored with all of them, from their original offsets.
    """
    feature = feature / jnp.maximum(jnp.linalg.norm(feature), 1e-12)
    sources, _, sources_valid = rank_imprints(
        view.features @ feature, view.openings, view.imprint_valid, opening, settings.sources,
        max_opening_difference_mm=settings.max_opening_difference_mm, exclude=exclude)
    offsets = settings.grid.offsets(valid_centroid(evidence.contact, evidence.contact_valid))
    few = _first_points(evidence, settings.screen_points)
    per_source = settings.grid.size

    def screen(source, T_source_sensor):
        T_source_sensor = align_depth(views, source, T_source_sensor, few, iterations=1)
        return log_likelihood(views, source, T_source_sensor, few, settings.coarse)

    screening = jax.vmap(lambda source: jax.vmap(lambda T: screen(source, T))(offsets))(sources)  # (sources, S)
    screening = jnp.where(sources_valid[:, None], screening, -jnp.inf).reshape(-1)
    kept_scores, kept = jax.lax.top_k(screening, min(settings.screened, screening.shape[0]))
    source = sources[kept // per_source]

    def score(source, T_source_sensor):
        T_source_sensor = align_depth(views, source, T_source_sensor, evidence)
        return (log_likelihood(views, source, T_source_sensor, evidence, settings.coarse),
                _take(view.T_object_sensor, source) @ T_source_sensor)

    scores, poses = jax.vmap(score)(source, _take(offsets, kept % per_source))
    scores = jnp.where(jnp.isfinite(kept_scores), scores, -jnp.inf)
    best_scores, best = jax.lax.top_k(scores, settings.new_hypotheses)
    return _take(poses, best), best_scores


def refine(view: LocalizationMap, views: SurfaceViews, belief: PoseBelief, T_object_reference: jaxlie.SE3,
           settings: BeliefSettings) -> jaxlie.SE3:
    """Step 3: ICP of all remembered touches at once from one hypothesis (reference frame)."""
    n = settings.registration_neighbours
    T_touches = T_object_reference @ belief.T_reference_touch  # (T,)
    landing = jax.vmap(lambda T, e: nearest_view(view, T, e))(T_touches, belief.evidence)
    used = settings.registration_points
    # Every touch's points against the n imprints around where that touch lands.
    candidates_ = jnp.repeat(views.neighbours[landing, :n], used, axis=0)  # (T * used, n)
    candidates_valid = jnp.repeat(views.neighbours_valid[landing, :n] & belief.touch_valid[:, None], used, axis=0)
    points = jax.vmap(lambda T, p: T @ p)(belief.T_reference_touch, belief.evidence.contact[:, :used])
    points_valid = belief.evidence.contact_valid[:, :used] & belief.touch_valid[:, None]
    estimate = icp(view, candidates_, candidates_valid, points.reshape(-1, 3), points_valid.reshape(-1),
                   T_object_reference, settings.icp)
    return estimate.T_object_sensor


def weigh(view: LocalizationMap, views: SurfaceViews, belief: PoseBelief, T_object_reference: jaxlie.SE3,
          settings: LikelihoodSettings) -> Float[Array, ""]:
    """Step 4: the log-likelihood of all remembered touches at one hypothesis."""
    T_touches = T_object_reference @ belief.T_reference_touch
    per_touch = jax.vmap(lambda e, T: touch_log_likelihood(view, views, e, T, settings))(belief.evidence, T_touches)
    return jnp.sum(jnp.where(belief.touch_valid, per_touch, 0.0))


def _keep_distinct(belief: PoseBelief, poses: jaxlie.SE3, scores: Float[Array, "N"], count: int,
                   duplicate_mm: float) -> tuple[jaxlie.SE3, Float[Array, "count"]]:
    """The ``count`` best poses, a pose within ``duplicate_mm`` of a better one dropped."""
    order = jnp.argsort(-scores)
    poses, scores = _take(poses, order), scores[order]
    probe = belief.replace(T_object_reference=poses)
    distance = jax.vmap(lambda T: hypothesis_distances(probe, T))(poses)  # (N, N)
    earlier = jnp.tril(jnp.ones_like(distance, bool), k=-1)  # [i, j]: j is better than i
    duplicate = jnp.any(earlier & (distance <= duplicate_mm) & jnp.isfinite(scores)[None, :], axis=1)
    scores = jnp.where(duplicate, -jnp.inf, scores)
    best_scores, best = jax.lax.top_k(scores, count)
    return _take(poses, best), best_scores


def update_belief(
    view: LocalizationMap,
    views: SurfaceViews,
    belief: PoseBelief,
    evidence: TouchEvidence,
    feature: Float[Array, "F"],
    opening: Float[Array, ""],
    T_reference_touch: jaxlie.SE3,
    settings: BeliefSettings = BeliefSettings(),
    *,
    exclude: int | Int[Array, ""] = -1,
) -> PoseBelief:
    """``belief`` after one more touch (see the module docstring). Pure; vmap and jit freely.

    Args:
        view: the object's map.
        views: its local surface views (:func:`~tactojax.localize.build_surface_views`).
        belief: the belief so far (:func:`empty_belief` before the first touch).
        evidence: the new touch (:func:`~tactojax.localize.touch_evidence`).
        feature: (F,) its retrieval features; opening: its gripper opening, mm.
        T_reference_touch: its sensor pose in the reference touch's sensor frame (identity for
            the first touch), from the kinematics.
        settings: parameters (static).
        exclude: a map imprint never used as a source (leave-one-out), -1 for none.

    Returns:
        the updated belief (never NaN); a touch without contact changes nothing (before any
        touch with contact, every hypothesis slot stays empty: no estimate).
    """
    before = belief
    first = ~jnp.any(belief.touch_valid)
    belief = remember(belief, evidence, T_reference_touch)
    T_object_touch, new_scores = candidates(view, views, evidence, feature, opening, settings, exclude)
    T_new = T_object_touch @ T_reference_touch.inverse()
    old_valid = jnp.isfinite(belief.log_weights) & ~first
    pooled = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), belief.T_object_reference, T_new)
    pooled_valid = jnp.concatenate([old_valid, jnp.isfinite(new_scores)])
    score = jax.vmap(lambda T: weigh(view, views, belief, T, settings.likelihood))
    scores = jnp.where(pooled_valid, score(pooled), -jnp.inf)
    _, chosen = jax.lax.top_k(scores, settings.refine)
    refined = jax.vmap(lambda T: refine(view, views, belief, T, settings))(_take(pooled, chosen))
    refined_scores = jnp.where(jnp.isfinite(scores[chosen]), score(refined), -jnp.inf)
    # A refinement that fits worse than its start keeps the start.
    better = refined_scores >= scores[chosen]
    pooled = jax.tree.map(lambda x, r: x.at[chosen].set(jnp.where(better[:, None], r, x[chosen])), pooled,
                          refined)
    scores = scores.at[chosen].set(jnp.maximum(refined_scores, scores[chosen]))
    scores = jnp.where(jnp.isfinite(scores), scores, -jnp.inf)
    poses, kept = _keep_distinct(belief, pooled, scores, settings.hypotheses, settings.duplicate_mm)
    any_valid = jnp.any(jnp.isfinite(kept))
    log_weights = kept - jax.nn.logsumexp(jnp.where(any_valid, kept, 0.0))
    log_weights = jnp.where(any_valid & jnp.isfinite(kept), log_weights, -jnp.inf)
    poses = jaxlie.SE3(jnp.where(jnp.isfinite(poses.wxyz_xyz), poses.wxyz_xyz, jaxlie.SE3.identity().wxyz_xyz))
    after = belief.replace(T_object_reference=poses, log_weights=log_weights)
    contact = jnp.any(evidence.contact_valid)
    return jax.tree.map(lambda new, old: jnp.where(contact, new, old), after, before)
