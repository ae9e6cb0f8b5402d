"""Which grasp next: the candidate whose predicted touch most raises P(within 2 mm) (active touch).

Beyond the paper (issue 28; Hebert et al., ICRA 2013, "the next best touch"). For every
candidate grasp and each of the belief's ``hypotheses`` most likely modes *h* (symmetric copies
and poses within 2 mm of a likelier one merged: they predict the same touch), the grasp's
touch is predicted from the map alone (:func:`~tactojax.localize.active.predict_grasp`). Were *h* the
truth, that touch would reweigh every hypothesis *h'* by the belief's own likelihood (the
geometric likelihood of its contact and no-contact points against the map's surface, at the
sensor pose the jaws report, with the belief's calibrated temperature and fusion exponent; the
appearance cue cannot be predicted and is left out). The expected gain of a grasp is the
belief-weighted mean over *h* of the objective after that reweighing, less its value now:

- ``"within"`` (default, task-aware): P(the most likely pose is within 2 mm, up to the
  object's symmetry), :meth:`~tactojax.localize.PoseBelief.probability_within` on the
  hypotheses;
- ``"entropy"``: minus the entropy of the modes' masses (symmetric copies are one mode).

A grasp predicted to miss under *h* brings no touch there, but its failure reweighs every *h'*
as the belief will (:func:`observe_failed_grasp`: it rules out the poses at which the grasp
would close). Everything has fixed shapes: one compilation per map, settings and candidate count,
vmapped over candidates (:func:`next_grasp`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from tactojax import _struct as struct
from tactojax.geometry import take
from tactojax.localize._belief import WITHIN_MM, PoseBelief, hypothesis_distances
from tactojax.localize._compile import top_level_jit
from tactojax.localize._likelihood import LikelihoodSettings, log_likelihood
from tactojax.localize._map import LocalizationMap
from tactojax.localize._predict_touch import (MarchingGrid, PredictedGrasp, PredictionSettings, predict_grasp,
                                              predicted_evidence)

# Top-down gripper at yaw 0 (as the simulator's grasp protocols): x along world x, closing
# axis y along world -y, approach z down.
_R_WORLD_GRIPPER_0 = jnp.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


@dataclass(frozen=True)
class ActiveSettings:
    """How grasps are proposed and ranked (static)."""

    hypotheses: int = 8
    """The belief's most likely modes the expectation runs over (:func:`leading_hypotheses`)."""
    fingers: int = 2
    """Fingers with a gel (2: both jaws)."""
    objective: str = "within"
    """``"within"``: expected gain in P(within 2 mm); ``"entropy"``: expected entropy reduction."""
    within_mm: float = WITHIN_MM
    """The error that P(within) is about, mm."""
    prediction: PredictionSettings = PredictionSettings()
    """Ray grid and gripper of the predicted touches."""
    contact_points: int = 32
    """Contact points of each predicted touch that the likelihood reads."""
    free_points: int = 32
    """No-contact points of each predicted touch that the likelihood reads."""
    likelihood: LikelihoodSettings = LikelihoodSettings(sigma_mm=0.5, margin_mm=0.5, interpolate=False)
    """Noise model of predicted touches: the belief's coarse one (a predicted touch is itself
    off by about 0.3-0.4 mm RMSE from the one the robot would feel; the surface read at the
    nearest cell)."""
    yaw_range_deg: float = 20.0
    """Proposed grasps: the closing axis within ±this of one of the object's mapped closing
    directions (its x axis turned by a multiple of 90 degrees about the vertical, at the pose
    a proposal is drawn from: the mapping protocol's turns), degrees."""
    oversample: int = 2
    """Proposed grasps: draws per kept candidate (those predicted to miss are dropped first)."""
    stop_probability: float = 0.95
    """The stopping rule: stop when the belief's P(within 2 mm) reaches this."""
    predicted_close_misses: float = 0.05
    """P(a grasp misses or collides | the map predicts it closes at the true pose): the
    prediction's own error rate, which bounds how strongly a failed grasp rules a pose out
    (:func:`observe_failed_grasp`)."""


@struct.dataclass
class GraspRanking:
    """Candidate grasps ranked by expected gain (C candidates)."""

    order: Int[Array, "C"]
    """Candidate indices, best first."""
    gain: Float[Array, "C"]
    """Expected gain of every candidate (input order): in P(within 2 mm), or in nats."""
    closes: Float[Array, "C"]
    """Belief mass (over the hypotheses used) of the poses at which the grasp closes on the object."""
    contact_area: Float[Array, "C"]
    """Predicted contact rays (both fingers) at the most likely pose (largest-contact baseline)."""


def gel_size_mm(view: LocalizationMap) -> tuple[float, float]:
    """(height, width) of the map's gel, mm."""
    height_px, width_px = view.packed_heightmaps.shape[1:]
    return (height_px * view.mm_per_px, width_px * view.mm_per_px)


def should_stop(belief: PoseBelief, threshold: float = 0.95) -> Bool[Array, ""]:
    """The stopping rule: the belief's calibrated P(within 2 mm) reached ``threshold``."""
    return belief.probability_within() >= threshold


@top_level_jit
def belief_error(belief: PoseBelief, T_world_object: jaxlie.SE3) -> Float[Array, ""]:
    """The paper's error of a belief whose object truly sits at ``T_world_object`` (evaluation,
    e.g. on a simulated cell): the RMSE between all its fused touches' contact points placed by
    its most likely pose and by the truth, up to the object's symmetry, mm; +inf for a belief
    without an estimate (no touch with contact)."""
    T_object_reference = T_world_object.inverse() @ belief.T_world_reference
    error = hypothesis_distances(belief, T_object_reference, symmetric=True)[jnp.argmax(belief.log_weights)]
    return jnp.where(belief.has_estimate, error, jnp.inf)


def leading_hypotheses(belief: PoseBelief, count: int) -> tuple[jaxlie.SE3, Float[Array, "M"], Float[Array, "M M"]]:
    """The belief's ``count`` most likely modes (:meth:`~tactojax.localize.PoseBelief.modes`:
    symmetric copies, and poses within 2 mm of a likelier one, merged into it), each at its most
    likely pose, as object poses in the world (mm); their renormalised probabilities; and their
    (M, M) symmetry-aware distances (the touches' cloud RMSE, mm).

    Copies of one pose predict the same touch: counted apart they would spend the expectation's
    few slots on one pose of a symmetric object."""
    _, mass = belief.modes()
    mass, index = jax.lax.top_k(mass, count)
    weights = mass / jnp.maximum(jnp.sum(mass), 1e-30)
    T_object_reference = take(belief.T_object_reference, index)
    T_world_object = belief.T_world_reference @ T_object_reference.inverse()
    probe = belief.replace(T_object_reference=T_object_reference)
    distance = jax.vmap(lambda T: hypothesis_distances(probe, T, symmetric=True))(T_object_reference)
    return T_world_object, weights, distance


def _objective(weights: Float[Array, "M"], distance: Float[Array, "M M"], mode: Int[Array, "M"],
               settings: ActiveSettings) -> Float[Array, ""]:
    """P(within) of a distribution over the hypotheses, or minus its modes' entropy."""
    if settings.objective == "within":
        best = jnp.argmax(weights)
        return jnp.sum(jnp.where(distance[best] <= settings.within_mm, weights, 0.0))
    mass = jnp.zeros_like(weights).at[mode].add(weights)
    return jnp.sum(jnp.where(mass > 0, mass * jnp.log(jnp.maximum(mass, 1e-30)), 0.0))


def _predicted_log_likelihoods(view: LocalizationMap, prediction: PredictedGrasp, T_world_object: jaxlie.SE3,
                               settings: ActiveSettings) -> Float[Array, "M"]:
    """(M,) untempered log-likelihood, at every hypothesis, of one predicted grasp's touches."""
    gel = gel_size_mm(view)
    T_object_world = T_world_object.inverse()  # (M,)

    def finger(heightmap, mask, free, T_world_sensor):
        evidence = predicted_evidence(heightmap, mask, free, gel, settings.prediction,
                                      contact_count=settings.contact_points, free_count=settings.free_points)
        return jax.vmap(lambda T: log_likelihood(view.surface, T @ T_world_sensor, evidence, settings.likelihood))(
            T_object_world)

    return jnp.sum(jax.vmap(finger)(prediction.heightmap, prediction.mask, prediction.free,
                                    prediction.T_world_sensor), axis=0)


def grasp_gain(view: LocalizationMap, grid: MarchingGrid, belief: PoseBelief, T_world_gripper: jaxlie.SE3,
               settings: ActiveSettings = ActiveSettings()) -> tuple[Float[Array, ""], Float[Array, ""], Float[Array, ""]]:
    """Expected gain of one candidate grasp (see the module docstring); the belief mass of the
    poses at which it closes; and its predicted contact rays at the most likely pose."""
    T_world_object, weights, distance = leading_hypotheses(belief, settings.hypotheses)
    mode = jnp.argmax(distance <= settings.within_mm, axis=1)  # the most likely hypothesis near each
    predictions = jax.vmap(lambda T: predict_grasp(grid, view.surface, T, T_world_gripper, gel_size_mm(view),
                                                   settings.prediction, fingers=settings.fingers))(T_world_object)
    scores = jax.vmap(lambda p: _predicted_log_likelihoods(view, p, T_world_object, settings))(predictions)  # (M, M)
    calibration = belief.calibration
    touches = jnp.maximum(belief.touches, 1).astype(jnp.float32)
    before, after = touches ** -calibration.fusion_exponent, (touches + settings.fingers) ** -calibration.fusion_exponent
    log_prior = jnp.log(jnp.maximum(weights, 1e-30))
    # The belief's log-likelihood of all touches, rescaled for one more grasp, plus the new one's.
    posterior = (after / before) * log_prior[None, :] + after * calibration.temperature * scores
    posterior = jnp.where(weights[None, :] > 0, posterior, -jnp.inf)
    posterior = jax.nn.softmax(posterior, axis=1)
    # Were h the truth and the grasp missed there, the failure itself reweighs every h'
    # (:func:`observe_failed_grasp`): it rules out the poses at which the grasp would close.
    failed = weights * jnp.where(predictions.valid, settings.predicted_close_misses, 1.0)
    failed = failed / jnp.maximum(jnp.sum(failed), 1e-30)
    posterior = jnp.where(predictions.valid[:, None], posterior, failed[None, :])
    value = jax.vmap(lambda w: _objective(w, distance, mode, settings))(posterior)
    gain = jnp.sum(weights * value) - _objective(weights, distance, mode, settings)
    closes = jnp.sum(jnp.where(predictions.valid, weights, 0.0))
    return gain, closes, jnp.sum(predictions.mask[0]).astype(jnp.float32)


@functools.partial(top_level_jit, static_argnames=("settings",))
def observe_failed_grasp(view: LocalizationMap, grid: MarchingGrid, belief: PoseBelief, T_world_gripper: jaxlie.SE3,
                         settings: ActiveSettings = ActiveSettings()) -> PoseBelief:
    """The belief after a grasp at ``T_world_gripper`` failed: the jaws closed on nothing, or
    hit the object on the way down. Its fingers felt no touch to fuse, but the failure is
    evidence: every hypothesis at which the map predicts that grasp closes cleanly on the object
    (:func:`~tactojax.localize.active.predict_grasp`) explains it only by a prediction error, at
    ``predicted_close_misses``; one at which it is predicted to miss or collide explains it
    fully. Without this, a belief that a grasp proved wrong would propose the same grasp again.

    Args:
        view, grid: the object's map and its marching grid.
        belief: the belief before the grasp (at least one touch; an empty belief is returned as is).
        T_world_gripper: the commanded gripper pose (fully open) in the belief's world frame, mm.
        settings: the prediction and ``predicted_close_misses`` (static).

    Returns:
        the belief with its hypotheses reweighed and the failure's likelihood added to its log
        evidence (its touches and poses unchanged).
    """
    T_world_object = belief.T_world_reference @ belief.T_object_reference.inverse()  # (M,)
    closes = jax.vmap(lambda T: predict_grasp(grid, view.surface, T, T_world_gripper, gel_size_mm(view),
                                              settings.prediction, fingers=settings.fingers).valid)(T_world_object)
    explained = jnp.where(closes, jnp.log(settings.predicted_close_misses), 0.0)
    log_weights = belief.log_weights + explained  # empty slots stay -inf
    total = jax.nn.logsumexp(log_weights)  # log P(failure | this map); -inf for an empty belief
    log_weights = jnp.where(jnp.isfinite(total), log_weights - total, belief.log_weights)
    # The failure's likelihood under this map joins its evidence (P(object) across maps).
    return belief.replace(log_weights=log_weights,
                          log_evidence=jnp.where(jnp.isfinite(total), belief.log_evidence + total, belief.log_evidence))


@functools.partial(top_level_jit, static_argnames=("settings",))
def next_grasp(view: LocalizationMap, grid: MarchingGrid, belief: PoseBelief, T_world_gripper: jaxlie.SE3,
               settings: ActiveSettings = ActiveSettings()) -> GraspRanking:
    """Candidate grasps ranked by expected gain (see the module docstring). Pure, jit-compiled
    once per map, settings and candidate count.

    Args:
        view: the object's map (its surface is what every touch is predicted from).
        grid: the map's :class:`~tactojax.localize.active.MarchingGrid` (:func:`~tactojax.localize.active.map_marching_grid`).
        belief: the belief so far (at least one touch).
        T_world_gripper: (C,) candidate gripper poses, commanded fully open, in the belief's
            world (robot) frame, mm.
        settings: hypotheses, objective, prediction (static).

    Returns:
        the :class:`GraspRanking`: the candidates that close at the largest belief mass (over
        the leading modes) come first, by gain among themselves; one that closes under no
        mode last.
    """
    gain, closes, area = jax.vmap(lambda T: grasp_gain(view, grid, belief, T, settings))(T_world_gripper)
    # A miss is a spent grasp, and the truth may lie outside the leading modes: the
    # candidates that close at the most of them come first, by gain among themselves.
    surest = closes >= jnp.max(closes) - 1e-6
    rank = jnp.where(closes > 0, gain + jnp.where(surest, 10.0, 0.0), -jnp.inf)
    return GraspRanking(order=jnp.argsort(-rank), gain=gain, closes=closes, contact_area=area)


def map_box(view: LocalizationMap) -> Float[Array, "2 3"]:
    """Object-frame bounds of the map's contact points (min, max), mm."""
    valid = view.points_valid & view.imprint_valid[:, None]
    points = view.points.reshape(-1, 3)
    valid = valid.reshape(-1)
    return jnp.stack([jnp.min(jnp.where(valid[:, None], points, jnp.inf), axis=0),
                      jnp.max(jnp.where(valid[:, None], points, -jnp.inf), axis=0)])


@functools.partial(top_level_jit, static_argnames=("count", "settings"))
def propose_grasps(key: PRNGKeyArray, view: LocalizationMap, grid: MarchingGrid, belief: PoseBelief, count: int,
                   settings: ActiveSettings = ActiveSettings()) -> tuple[jaxlie.SE3, Bool[Array, "C"]]:
    """``count`` candidate grasps that the map says close on the object, from the belief's
    modes: each draw picks one of the ``hypotheses`` most likely poses (by probability), then a
    top-down gripper pose (the simulator's convention) with yaw uniform within
    ±``yaw_range_deg`` and centre uniform over the map's bounding box at that pose as seen in
    the plane of the gripper, centred on it along the closing axis (as the new-grasps
    protocol). Of ``oversample * count`` draws, those predicted to close on the object at the
    pose they were drawn from come first.

    Returns:
        (C,) commanded gripper poses in the belief's world frame (mm), and whether each is
        predicted to close on the object.
    """
    draws = count * settings.oversample
    bounds = map_box(view)
    box = jnp.stack(jnp.meshgrid(*bounds.T, indexing="ij"), axis=-1).reshape(-1, 3)  # (8, 3)
    T_world_object, weights, _ = leading_hypotheses(belief, settings.hypotheses)
    mode_key, turn_key, yaw_key, u_key, v_key = jax.random.split(key, 5)
    mode = jax.random.choice(mode_key, settings.hypotheses, (draws,), p=weights)
    x_axis = jax.vmap(lambda T: T.rotation().as_matrix()[:, 0])(take(T_world_object, mode))
    turn = jnp.arctan2(x_axis[:, 1], x_axis[:, 0]) + 0.5 * jnp.pi * jax.random.randint(turn_key, (draws,), 0, 4)
    yaw = turn + jnp.deg2rad(settings.yaw_range_deg) * jax.random.uniform(yaw_key, (draws,), minval=-1.0, maxval=1.0)

    def pose(T_world_object_, yaw_, u_draw, v_draw):
        corners = jax.vmap(lambda p: T_world_object_ @ p)(box)
        rotation = jaxlie.SO3.from_z_radians(yaw_).as_matrix() @ _R_WORLD_GRIPPER_0
        u, c, z = corners @ rotation[:, 0], corners @ rotation[:, 1], corners[:, 2]
        centre = (jnp.min(u) + u_draw * (jnp.max(u) - jnp.min(u))) * rotation[:, 0] + 0.5 * (
            jnp.min(c) + jnp.max(c)) * rotation[:, 1]
        centre = centre.at[2].set(jnp.min(z) + v_draw * (jnp.max(z) - jnp.min(z)))
        return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(rotation), centre)

    T_drawn = take(T_world_object, mode)
    poses = jax.vmap(pose)(T_drawn, yaw, jax.random.uniform(u_key, (draws,)), jax.random.uniform(v_key, (draws,)))
    closes = jax.vmap(lambda T_object, T: predict_grasp(grid, view.surface, T_object, T, gel_size_mm(view),
                                                        settings.prediction, fingers=settings.fingers).valid)(
        T_drawn, poses)
    _, keep = jax.lax.top_k(closes.astype(jnp.float32) + jnp.linspace(0.5, 0.0, draws), count)
    return take(poses, keep), closes[keep]
