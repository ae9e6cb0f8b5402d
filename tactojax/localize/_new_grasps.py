"""Localization of *new* grasps, off the mapping grid: single touches and fused episodes.

The headline evaluation (DESIGN.md, "Evaluation"): a test set of grasps that are not in the map
(``tactojax simulate OBJECT --protocol grasps``), in episodes during which the object stays
put. Every grasp's sensor-finger touch is localized alone with each method; with the belief,
the first k grasps of each episode (one or both fingers) are also fused, k = 1..K, the touches
related by their kinematics. The error is the paper's: the RMSE between the touches' true
contact clouds at their true and at their estimated poses (over all fused touches), with the
symmetry-aware value for symmetric objects; the belief's predicted P(error <= 2 mm) is
compared with what happened (calibration).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from flax import struct
from jaxtyping import Array, Bool, Float
from tqdm.auto import tqdm

from tactojax.localize._baselines import baseline_estimate, parse_method
from tactojax.localize._belief import WITHIN_MM, BeliefSettings, empty_belief, update_belief
from tactojax.localize._evaluate import moment_rmse
from tactojax.localize._map import LocalizationMap, Touch
from tactojax.localize._sharded import batch_mesh, in_batches, over_batch, per_device, run_sharded

CALIBRATION_BINS = tuple(float(x) for x in np.linspace(0.0, 1.0, 6))
"""Bins of the predicted P(error <= 2 mm) in the reliability diagram."""


@struct.dataclass
class TestEpisodes:
    """E episodes of G grasps with F fingers each, as localization reads them."""

    heightmaps: Float[Array, "E G F H W"]
    """Predicted heightmaps, mm."""
    masks: Bool[Array, "E G F H W"]
    """Predicted (observed) contact masks."""
    features: Float[Array, "E G F D"]
    """Retrieval features."""
    openings: Float[Array, "E G"]
    """Gripper openings, mm."""
    T_object_sensor: jaxlie.SE3
    """(E, G, F) true sensor poses in the object (map) frame: the truth, and the kinematics
    (only their relative poses within an episode reach the localizer)."""
    cloud_mean: Float[Array, "E G F 3"]
    """Mean of every touch's true contact cloud, sensor frame, mm (the error metric)."""
    cloud_covariance: Float[Array, "E G F 3 3"]
    """Its covariance, mm^2."""

    def sensor_touches(self) -> TestEpisodes:
        """Every grasp's sensor-finger touch (finger 0) as an episode of its own: (E * G, 1, 1) episodes."""
        def alone(x):
            return x[:, :, :1].reshape(-1, 1, 1, *x.shape[3:])

        return TestEpisodes(heightmaps=alone(self.heightmaps), masks=alone(self.masks), features=alone(self.features),
                            openings=self.openings.reshape(-1, 1),
                            T_object_sensor=jax.tree.map(alone, self.T_object_sensor),
                            cloud_mean=alone(self.cloud_mean), cloud_covariance=alone(self.cloud_covariance))


@dataclass
class EpisodeErrors:
    """Errors of one method and number of fused grasps, one value per localization."""

    method: str
    fingers: int
    grasps: int
    fused: bool
    """False: every grasp's sensor-finger touch alone; True: episodes fused over ``grasps`` grasps."""
    rmse: np.ndarray
    """(Q,) RMSE over the fused touches' true clouds, mm."""
    symmetric_rmse: np.ndarray
    """(Q,) the same, up to the object's symmetries, mm."""
    translation: np.ndarray
    """(Q,) translation error of the first touch's sensor pose, mm."""
    rotation: np.ndarray
    """(Q,) its rotation error, degrees."""
    probability: np.ndarray
    """(Q,) predicted P(rmse <= 2 mm) (the belief; NaN for the other methods)."""
    nll_truth: np.ndarray
    """(Q,) negative log of the belief's mass within 2 mm of the truth (NaN for the other methods)."""
    covered: np.ndarray
    """(Q,) whether the belief's 90 % credible set holds the truth (within 2 mm; False for the others)."""

    def summary(self, *, symmetric: bool = False) -> dict:
        """JSON-ready medians, shares within 1/2/5 mm and calibration (on the symmetry-aware
        error where ``symmetric``)."""
        error = self.symmetric_rmse if symmetric else self.rmse
        out = {"method": self.method, "fingers": self.fingers, "grasps": self.grasps, "fused": self.fused,
               "count": int(len(error)),
               "median_rmse_mm": float(np.median(self.rmse)),
               "median_symmetric_rmse_mm": float(np.median(self.symmetric_rmse)),
               "within_mm": {str(t): float(np.mean(error <= t)) for t in (1, 2, 5)},
               "median_translation_mm": float(np.median(self.translation)),
               "median_rotation_deg": float(np.median(self.rotation))}
        if np.all(np.isfinite(self.probability)):
            out["calibration"] = calibration(self.probability, error <= WITHIN_MM)
            out["mean_nll_truth"] = float(np.mean(self.nll_truth))
            out["coverage_90"] = float(np.mean(self.covered))
        return out


MIN_BIN_COUNT = 10
"""Bins of predicted probability holding fewer beliefs than this are left out of the gaps."""


def calibration(predicted: np.ndarray, happened: np.ndarray, bins=CALIBRATION_BINS, *,
                min_count: int = MIN_BIN_COUNT, draws: int = 2000) -> dict:
    """Reliability: per bin of predicted probability, its mean and the observed share; the
    largest gap between them; and what that gap would be by chance alone.

    With a few dozen beliefs per bin, even a perfectly calibrated predictor shows gaps of
    0.1 or more. So the outcomes are also drawn ``draws`` times as a calibrated predictor would
    see them (each belief right with its own predicted probability; a fixed seed), and the
    largest gap over the bins holding ``min_count`` beliefs is compared with those draws.

    Returns:
        ``bins`` (bin, count, predicted, observed), ``max_gap`` (over every non-empty bin),
        ``max_gap_binned`` (over the bins holding ``min_count`` or more; None if none),
        ``calibrated_max_gap_95`` (the 95th percentile of that gap for a calibrated predictor
        with the same predictions), ``calibrated_p`` (the share of those draws whose gap is as
        large as the observed one: small means miscalibrated), and ``brier``.
    """
    predicted, happened = np.asarray(predicted, np.float64), np.asarray(happened, bool)
    index = np.clip(np.digitize(predicted, bins[1:-1]), 0, len(bins) - 2)
    rows = []
    for b in range(len(bins) - 1):
        inside = index == b
        rows.append({"bin": [bins[b], bins[b + 1]], "count": int(inside.sum()),
                     "predicted": float(predicted[inside].mean()) if inside.any() else None,
                     "observed": float(happened[inside].mean()) if inside.any() else None})
    gaps = [abs(r["predicted"] - r["observed"]) for r in rows if r["count"]]
    out = {"bins": rows, "max_gap": float(max(gaps)) if gaps else None, "max_gap_binned": None,
           "calibrated_max_gap_95": None, "calibrated_p": None,
           "brier": float(np.mean((predicted - happened) ** 2)) if len(predicted) else None}
    full = [b for b, r in enumerate(rows) if r["count"] >= min_count]
    if full:
        members = np.stack([index == b for b in full]).astype(np.float64)  # (B, N)
        mean_predicted = members @ predicted / members.sum(axis=1)
        observed_gap = float(np.max(np.abs(members @ happened / members.sum(axis=1) - mean_predicted)))
        outcomes = np.random.default_rng(0).random((draws, len(predicted))) < predicted  # (draws, N)
        chance = np.max(np.abs(outcomes @ members.T / members.sum(axis=1) - mean_predicted), axis=1)
        out.update(max_gap_binned=observed_gap, calibrated_max_gap_95=float(np.percentile(chance, 95)),
                   calibrated_p=float(np.mean(chance >= observed_gap - 1e-12)))
    return out


def _errors(T_true: jaxlie.SE3, T_estimate: jaxlie.SE3, mean, covariance, valid, symmetries: jaxlie.SE3):
    """RMSE over a set of touches (T,) and its symmetry-aware value; the first touch's pose errors."""
    per_touch_rmse = jax.vmap(moment_rmse)  # over touches, each with its own cloud
    per_touch = per_touch_rmse(mean, covariance, T_true, T_estimate)  # (T,)
    count = jnp.maximum(jnp.sum(valid), 1)
    rmse = jnp.sqrt(jnp.sum(jnp.where(valid, per_touch**2, 0.0)) / count)
    per_symmetry = jax.vmap(lambda S: per_touch_rmse(mean, covariance, T_true, S @ T_estimate))(symmetries)  # (S, T)
    symmetric = jnp.sqrt(jnp.min(jnp.sum(jnp.where(valid, per_symmetry**2, 0.0), axis=1)) / count)
    first_true, first_estimate = (jax.tree.map(lambda x: x[0], T) for T in (T_true, T_estimate))
    rotation = jnp.rad2deg(jnp.linalg.norm((first_true.inverse() @ first_estimate).rotation().log()))
    translation = jnp.linalg.norm(first_true.translation() - first_estimate.translation())
    return rmse, jnp.minimum(rmse, symmetric), translation, rotation


@functools.partial(jax.jit, static_argnames=("method", "points_per_touch", "settings", "batch_size", "mesh"))
def _single_touches(view: LocalizationMap, touches: TestEpisodes, method, points_per_touch: int,
                    settings: BeliefSettings, batch_size: int, mesh):
    """Touches localized alone: ``touches`` holds one per item (leading axis T), as (T, 1, 1)
    episodes; (T,) errors, ``batch_size`` at a time on each device of ``mesh``."""
    def one(view, touch: TestEpisodes):
        take = lambda x: x[0, 0]  # noqa: E731
        T, m, c = jax.tree.map(take, touch.T_object_sensor), take(touch.cloud_mean), take(touch.cloud_covariance)
        query = episode_touch(touch, 0, 0)
        if method.kind == "belief":
            belief = update_belief(view, empty_belief(view, settings), query, jaxlie.SE3.identity(), settings)
            estimate, probability = belief.best, belief.probability_within()
            nll, covered = belief.truth_scores(T)
        else:
            estimate = baseline_estimate(jax.random.key(0), view, query, method,
                                         points_per_touch=points_per_touch).T_object_sensor
            probability, nll, covered = jnp.float32(jnp.nan), jnp.float32(jnp.nan), jnp.bool_(False)
        one_touch = lambda x: x[None]  # noqa: E731
        errors = _errors(jax.tree.map(one_touch, T), jax.tree.map(one_touch, estimate), m[None], c[None],
                         jnp.ones(1, bool), view.symmetries)
        return (*errors, probability, nll, covered)

    return over_batch(lambda view, touches: in_batches(lambda t: one(view, t), touches, batch_size), mesh)(
        view, touches)


def episode_touch(episode: TestEpisodes, g, finger: int) -> Touch:
    """Grasp ``g``'s touch of finger ``finger`` in one episode."""
    return Touch(heightmap=episode.heightmaps[g, finger], mask=episode.masks[g, finger],
                 feature=episode.features[g, finger], opening=episode.openings[g])


def fuse_episode(view: LocalizationMap, episode: TestEpisodes, fingers: int, settings: BeliefSettings, observe):
    """Fuse an episode's grasps into one belief, grasp by grasp (``fingers`` touches each, at
    their sensor poses: the kinematics), and return ``observe(belief, g)`` after every grasp
    ``g``, stacked along a leading (G,) axis. Pure; the callers jit it.

    To observe after every touch, pass the episode as G x F grasps of one finger each.
    """
    def grasp(belief, g):
        for finger in range(fingers):
            T_touch = jax.tree.map(lambda x: x[g, finger], episode.T_object_sensor)
            belief = update_belief(view, belief, episode_touch(episode, g, finger), T_touch, settings)
        return belief, observe(belief, g)

    _, out = jax.lax.scan(grasp, empty_belief(view, settings), jnp.arange(episode.openings.shape[0]))
    return out


def _fused_episode(view: LocalizationMap, episode: TestEpisodes, fingers: int, settings: BeliefSettings):
    """One episode's belief after each of its G grasps: (G,) errors and probabilities."""
    grasps = episode.openings.shape[0]

    def observe(belief, g):
        # Error over every touch fused so far (grasps 0..g, the fingers used). The sensor poses
        # are given in the object frame here, so the belief's world frame is the object's.
        T_true = jax.tree.map(lambda x: x[:, :fingers].reshape(-1, *x.shape[2:]), episode.T_object_sensor)
        T_estimate = belief.sensor_pose(T_true)
        valid = (jnp.arange(grasps)[:, None] <= g).repeat(fingers, axis=1).reshape(-1)
        errors = _errors(T_true, T_estimate, episode.cloud_mean[:, :fingers].reshape(-1, 3),
                         episode.cloud_covariance[:, :fingers].reshape(-1, 3, 3), valid, view.symmetries)
        return (*errors, belief.probability_within(), *belief.truth_scores(belief.T_world_reference))

    return fuse_episode(view, episode, fingers, settings, observe)


@functools.partial(jax.jit, static_argnames=("fingers", "settings", "batch_size", "mesh"))
def _fused_episodes(view: LocalizationMap, episodes: TestEpisodes, fingers: int, settings: BeliefSettings,
                    batch_size: int, mesh):
    """Every episode's belief after each of its G grasps: (E, G) errors and probabilities,
    ``batch_size`` episodes at a time on each device of ``mesh``."""
    def local(view, episodes):
        return in_batches(lambda episode: _fused_episode(view, episode, fingers, settings), episodes, batch_size)

    return over_batch(local, mesh)(view, episodes)


def evaluate_new_grasps(
    view: LocalizationMap,
    episodes: TestEpisodes,
    methods=("cti-icp-5", "belief"),
    *,
    fingers: int = 1,
    settings: BeliefSettings = BeliefSettings(),
    points_per_touch: int = 128,
    single_touches: bool = True,
    devices=None,
    touch_batch_size: int = 8,
    episode_batch_size: int = 1,
    progress: bool = False,
) -> list[EpisodeErrors]:
    """Single-touch errors of every method, and the belief fused over 1..G grasps.

    Touches and episodes run as one compiled program each, their batch sharded over ``devices``
    (a mesh with one ``batch`` axis), each device localizing ``touch_batch_size`` touches
    (``episode_batch_size`` episodes) at once, vmapped; the program is called once per chunk of
    a few such batches per device, which bounds the memory.

    Args:
        view: the object's map (its symmetries and calibration are used).
        episodes: the test grasps (:class:`TestEpisodes`, F >= ``fingers``).
        methods: method names (``"belief"`` or a baseline of
            :func:`~tactojax.localize.baselines.localize_baseline`).
        fingers: fingers fused per grasp (1 or 2).
        settings: belief parameters.
        points_per_touch: contact points of the ICP baselines.
        single_touches: localize every grasp's sensor-finger touch alone with each method
            (False: only the belief's fused episodes).
        devices: the devices the batch is sharded over (default: every local device).
        touch_batch_size, episode_batch_size: single touches and fused episodes a device
            localizes at once (vmapped; 1: one at a time). The results do not depend on the
            devices; they can move by rounding with these sizes, and the belief's discrete choices
            can follow (episodes go one at a time by default: the reference results).
        progress: show progress bars (per chunk).

    Returns:
        one :class:`EpisodeErrors` per method for single touches (``grasps`` 1, ``fingers`` 1;
        if ``single_touches``), then, for the belief, one per number of fused grasps with
        ``fingers`` fingers.
    """
    if fingers not in (1, 2) or episodes.heightmaps.shape[2] < fingers:
        raise ValueError(f"fingers must be 1 or 2 and the test set must have them (it has "
                         f"{episodes.heightmaps.shape[2]})")
    mesh = batch_mesh(devices)
    touches = episodes.sensor_touches()
    count = touches.openings.shape[0]
    touch_batch_size = min(touch_batch_size, count)  # (a small test set: no padded batch)
    results = []
    for name in methods if single_touches else ():  # the touches: (E * G, 1, 1) episodes
        method = parse_method(name)
        program = functools.partial(_single_touches, method=method, points_per_touch=points_per_touch,
                                    settings=settings, batch_size=touch_batch_size, mesh=mesh)
        with tqdm(total=count, desc=f"single touches ({method.name})", unit="touch", disable=not progress) as bar:
            out = run_sharded(program, view, touches, mesh=mesh, bar=bar,
                              per_device=per_device(count, mesh, touch_batch_size))
        results.append(EpisodeErrors(method.name, 1, 1, False, *out))
    if any(parse_method(name).kind == "belief" for name in methods):
        count = episodes.openings.shape[0]
        episode_batch_size = min(episode_batch_size, count)
        program = functools.partial(_fused_episodes, fingers=fingers, settings=settings,
                                    batch_size=episode_batch_size, mesh=mesh)
        with tqdm(total=count, desc=f"fused episodes ({fingers} finger{'s' * (fingers > 1)})", unit="episode",
                  disable=not progress) as bar:
            out = run_sharded(program, view, episodes, mesh=mesh, bar=bar,
                              per_device=per_device(count, mesh, episode_batch_size))
        for g in range(episodes.openings.shape[1]):  # out: (E, G) each
            results.append(EpisodeErrors("belief", fingers, g + 1, True, *(x[:, g] for x in out)))
    return results
