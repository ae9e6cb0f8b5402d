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
would close).

A miss is a spent grasp, so the candidates likeliest to close are ranked first. The modes say
where a grasp closes only if the belief's search found the truth's mode, which the belief itself
rates (:meth:`~tactojax.localize.BeliefCalibration.found_probability`: low after grazing
touches). Where it did not, only a grasp across a contact already felt
(:func:`closes_across_felt`) is known to touch the object, so P(close) is the modes' closing
mass weighed by P(found), plus P(not found) for those, and among the likeliest to close the
expected objective weighs the gain by P(found) and, for those, P(found) one grasp later by
P(not found). :func:`propose_grasps` draws half its candidates across a felt contact.

Everything has fixed shapes: one compilation per map, settings and candidate count, vmapped over
candidates (:func:`next_grasp`).
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
from tactojax.localize._belief import WITHIN_MM, PoseBelief, hypothesis_distances, reference_cloud
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
    across_felt: float = 0.5
    """Proposed grasps: the share drawn across a contact already felt (:func:`propose_grasps`):
    through one of the touches' contact points, closing at right angles (within
    ±``yaw_range_deg``) to the grasp that felt it. They touch the object whatever its pose."""
    clearance_mm: float = 5.0
    """A grasp is counted on to close at a pose only if its open jaws start at least this far
    from the object there (:attr:`~tactojax.localize.active.PredictedGrasp.clearance_mm`): a
    grasp that barely fits flips to a collision with a few mm of pose or prediction error, mm."""
    felt_margin_mm: float = 2.0
    """A felt contact point counts as inside a grasp's swept gels (:func:`closes_across_felt`)
    this far inside their border, mm."""
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
    """Belief mass (over the hypotheses used) of the poses at which the grasp closes on the object,
    its jaws starting ``clearance_mm`` or more from it."""
    across_felt: Bool[Array, "C"]
    """Whether the grasp closes across a contact already felt (it touches the object whatever
    its pose: :func:`closes_across_felt`)."""
    close_probability: Float[Array, "C"]
    """P(the grasp closes on the object): ``closes`` where the belief's search found the truth's
    mode; where it did not, 1 for a grasp across a felt contact (``across_felt``) and 0 for any
    other; weighed by the belief's own P(search found)."""
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
               settings: ActiveSettings = ActiveSettings()) -> tuple[Float[Array, ""], ...]:
    """Expected gain of one candidate grasp (see the module docstring); the belief mass (over the
    leading modes) of the poses at which it closes, its jaws starting ``clearance_mm`` or more
    from the object; and its predicted contact rays at the most likely pose."""
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
    closes = jnp.sum(jnp.where(predictions.valid & (predictions.clearance_mm >= settings.clearance_mm), weights, 0.0))
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
        the :class:`GraspRanking`: the candidates likeliest to close on the object
        (``close_probability`` within ``predicted_close_misses``, or within P(search missed), of
        the likeliest) come first, by expected objective among themselves (the gain where the
        search found the truth; P(found) one grasp later for a grasp across a felt contact where
        it did not); one with no chance of closing last.
    """
    gain, closes, area = jax.vmap(lambda T: grasp_gain(view, grid, belief, T, settings))(T_world_gripper)
    felt, pressing, felt_valid = felt_contacts(belief)
    across = jax.vmap(lambda T: closes_across_felt(T, felt, pressing, felt_valid, gel_size_mm(view), settings))(
        T_world_gripper)
    # A miss is a spent grasp. The leading modes say where a grasp closes only if the belief's
    # search found the truth's mode. Where it did not (its hypotheses can be turned by a right
    # angle: the screwdriver lying along the jaws), only a grasp across a felt contact is known
    # to touch the object. The candidates likeliest to close come first (differences below the
    # prediction's own error rate, or below the chance that the modes are wrong, are none).
    # Among them, the expected objective: the gain where the search found the truth; where it
    # did not, a grasp that surely closes gives it another touch, and P(found) one grasp later.
    found = belief.found_probability()
    close_probability = found * closes + (1.0 - found) * across
    found_after = belief.found_probability(more_touches=settings.fingers)
    value = found * gain + (1.0 - found) * across * found_after
    tolerance = jnp.maximum(settings.predicted_close_misses, 1.0 - found)
    surest = close_probability >= jnp.max(close_probability) - tolerance
    rank = jnp.where(close_probability > 0, value + jnp.where(surest, 10.0, 0.0), -jnp.inf)
    return GraspRanking(order=jnp.argsort(-rank), gain=gain, closes=closes, across_felt=across,
                        close_probability=close_probability, contact_area=area)


def felt_contacts(belief: PoseBelief) -> tuple[Float[Array, "N 3"], Float[Array, "N 3"], Bool[Array, "N"]]:
    """Every contact point of the touches the belief holds, in its world (robot) frame, mm: where
    the object's surface is known to be whatever its pose; the pressing direction of the touch
    that felt each (its gel's normal, into the object: the closing axis of that grasp); and which
    are valid. (T * P, 3), (T * P, 3) and (T * P,)."""
    points, valid = reference_cloud(belief)
    points = jax.vmap(lambda q: belief.T_world_reference @ q)(points)
    pressing = jax.vmap(lambda T: T.rotation().as_matrix()[:, 2])(belief.T_world_reference @ belief.T_reference_touch)
    return points, jnp.repeat(pressing, belief.evidence.contact.shape[1], axis=0), valid


def closes_across_felt(T_world_gripper: jaxlie.SE3, points: Float[Array, "N 3"], pressing: Float[Array, "N 3"],
                       valid: Bool[Array, "N"], gel_size_mm: tuple[float, float],
                       settings: ActiveSettings = ActiveSettings()) -> Bool[Array, ""]:
    """Whether a grasp closes across a felt contact: its open jaws sweep their gels over one of
    ``points`` (felt contact points, world frame, mm; ``felt_margin_mm`` inside the gels'
    border) with a closing axis at least 45 degrees from the grasp that felt it (``pressing``),
    and every felt point lies between the open jaws along that axis. Such a grasp touches the
    object whatever its pose: a point of its surface lies in the jaws' path. (A jaw may still
    start inside the object where it was not felt: along the felt grasp's own axis, the object
    beyond the contacts felt is unknown, and on the screwdriver lying along the jaws a jaw
    started inside it as often as not, so that axis is excluded.)"""
    height, width = gel_size_mm
    local = jax.vmap(lambda q: T_world_gripper.inverse() @ q)(points)  # gripper frame: x along the jaw, z approach
    facing = ((jnp.abs(local[:, 0]) <= 0.5 * width - settings.felt_margin_mm)
              & (jnp.abs(local[:, 2]) <= 0.5 * height - settings.felt_margin_mm))
    between = jnp.abs(local[:, 1]) < 0.5 * settings.prediction.max_opening_mm - settings.felt_margin_mm
    closing_axis = T_world_gripper.rotation().as_matrix()[:, 1]
    across = jnp.abs(pressing @ closing_axis) <= jnp.cos(jnp.pi / 4)
    return jnp.any(facing & between & across & valid) & jnp.all(between | ~valid)


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
    protocol). Of ``oversample`` times as many draws as are kept, those predicted to close on
    the object at the pose they were drawn from are kept first. A share ``across_felt`` of the
    candidates (first) are instead drawn across a contact already felt (:func:`_across_felt`):
    they touch the object whatever its pose, which is what counts when the belief's search has
    likely missed the truth (:func:`next_grasp`).

    Returns:
        (C,) commanded gripper poses in the belief's world frame (mm), and whether each is
        predicted to close on the object (at the pose it was drawn from; the most likely for
        those across a felt contact).
    """
    across = int(round(count * settings.across_felt))
    drawn = count - across
    draws = drawn * settings.oversample
    bounds = map_box(view)
    box = jnp.stack(jnp.meshgrid(*bounds.T, indexing="ij"), axis=-1).reshape(-1, 3)  # (8, 3)
    T_world_object, weights, _ = leading_hypotheses(belief, settings.hypotheses)
    mode_key, turn_key, yaw_key, u_key, v_key, felt_key = jax.random.split(key, 6)
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

    def closes(T_object, T_gripper):
        return predict_grasp(grid, view.surface, T_object, T_gripper, gel_size_mm(view), settings.prediction,
                             fingers=settings.fingers).valid

    T_drawn = take(T_world_object, mode)
    poses = jax.vmap(pose)(T_drawn, yaw, jax.random.uniform(u_key, (draws,)), jax.random.uniform(v_key, (draws,)))
    drawn_closes = jax.vmap(closes)(T_drawn, poses)
    _, keep = jax.lax.top_k(drawn_closes.astype(jnp.float32) + jnp.linspace(0.5, 0.0, draws), drawn)
    felt = _across_felt(felt_key, belief, across, gel_size_mm(view), settings)
    felt_closes = jax.vmap(lambda T: closes(take(T_world_object, 0), T))(felt)
    poses = jax.tree.map(lambda x, y: jnp.concatenate([x, y]), felt, take(poses, keep))
    return poses, jnp.concatenate([felt_closes, drawn_closes[keep]])


def _across_felt(key: PRNGKeyArray, belief: PoseBelief, draws: int, gel_size_mm: tuple[float, float],
                 settings: ActiveSettings) -> jaxlie.SE3:
    """(draws,) top-down grasps across a felt contact: each through one of the belief's contact
    points (uniform over them), closing at right angles to the touch that felt it (within
    ±``yaw_range_deg``), the gels' centre moved up to a quarter of their width into the object
    (along that touch's pressing direction) and up to an eighth of their height up or down: the
    point stays inside the swept gels (:func:`closes_across_felt`)."""
    height, width = gel_size_mm
    points, pressing, valid = felt_contacts(belief)
    point_key, yaw_key, in_key, up_key = jax.random.split(key, 4)
    index = jax.random.choice(point_key, points.shape[0], (draws,), p=valid / jnp.maximum(jnp.sum(valid), 1))
    inward = pressing[index].at[:, 2].set(0.0)
    inward = inward / jnp.maximum(jnp.linalg.norm(inward, axis=1, keepdims=True), 1e-9)
    # Gripper x (along the jaws) along the felt touch's pressing direction: closing across it.
    yaw = jnp.arctan2(inward[:, 1], inward[:, 0]) + jnp.deg2rad(settings.yaw_range_deg) * jax.random.uniform(
        yaw_key, (draws,), minval=-1.0, maxval=1.0)
    centre = (points[index] + 0.25 * width * jax.random.uniform(in_key, (draws, 1)) * inward
              + jnp.array([0.0, 0.0, 0.125 * height]) * jax.random.uniform(up_key, (draws, 1), minval=-1.0, maxval=1.0))
    rotation = jax.vmap(lambda y: jaxlie.SO3.from_z_radians(y).as_matrix() @ _R_WORLD_GRIPPER_0)(yaw)
    return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(rotation), centre)
