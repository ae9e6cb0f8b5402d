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
from tqdm.auto import tqdm

from tactojax.localize._baselines import baseline_estimate, parse_method
from tactojax.localize._belief import WITHIN_MM, BeliefSettings, PoseBelief
from tactojax.localize._compare import finite_or_none, share_interval
from tactojax.localize._compile import top_level_jit
from tactojax.localize._episode_beliefs import (
    TestEpisodes,
    alone_steps,
    episode_beliefs,
    episode_touch,
    fused_steps,
    sequence_touches,
)
from tactojax.localize._evaluate import closest_copy_square, moment_rmse
from tactojax.localize._map import LocalizationMap
from tactojax.localize._sharded import batch_mesh, in_batches, over_batch, run_sharded

CALIBRATION_BINS = tuple(float(x) for x in np.linspace(0.0, 1.0, 6))
"""Bins of the predicted P(error <= 2 mm) in the reliability diagram."""


@dataclass
class EpisodeErrors:
    """Errors of one method and number of fused grasps, one value per localization."""

    method: str
    fingers: int
    grasps: int
    fused: bool
    """False: every grasp's sensor-finger touch alone; True: episodes fused over ``grasps`` grasps."""
    rmse: np.ndarray
    """(Q,) RMSE over the fused touches' true clouds, mm (+inf: no estimate, the belief felt no contact)."""
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
        """JSON-ready medians, shares within 1/2/5 mm (with the 95 % interval of the share within
        2 mm), calibration (on the symmetry-aware error where ``symmetric``), and every
        localization's errors and predicted P(within 2 mm), in order, under ``per_localization``
        (for a paired comparison of two runs on the same test set: :func:`compare_evaluations`).
        A localization without an estimate (no contact felt) counts as a failure; its error is
        None in the JSON and ``no_estimate`` counts them."""
        error = self.symmetric_rmse if symmetric else self.rmse
        out = {"method": self.method, "fingers": self.fingers, "grasps": self.grasps, "fused": self.fused,
               "count": int(len(error)),
               "median_rmse_mm": finite_or_none(np.median(self.rmse)),
               "median_symmetric_rmse_mm": finite_or_none(np.median(self.symmetric_rmse)),
               "within_mm": {str(t): float(np.mean(error <= t)) for t in (1, 2, 5)},
               "within_2mm_interval": share_interval(int(np.sum(error <= WITHIN_MM)), len(error)),
               "median_translation_mm": finite_or_none(np.median(self.translation)),
               "median_rotation_deg": finite_or_none(np.median(self.rotation)),
               "no_estimate": int(np.sum(~np.isfinite(error))),
               "per_localization": {"rmse_mm": [finite_or_none(x) for x in self.rmse],
                                    "symmetric_rmse_mm": [finite_or_none(x) for x in self.symmetric_rmse]}}
        if np.all(np.isfinite(self.probability)):
            out["per_localization"]["p_within_2mm"] = self.probability.tolist()
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


def calibration_gap(table: dict) -> str:
    """The gap the calibration targets judge, for a table: the largest over the bins holding
    ``MIN_BIN_COUNT`` or more beliefs, and in brackets the chance that a calibrated belief with
    the same predictions shows one as large (``p``; small: miscalibrated). "-" where no bin holds
    that many. (The largest gap over *every* bin, ``max_gap``, is set by bins of one or two
    beliefs whenever there are some.)"""
    if table["max_gap_binned"] is None:
        return "-"
    return f"{table['max_gap_binned']:.2f} (p {table['calibrated_p']:.2f})"


def _errors(T_true: jaxlie.SE3, T_estimate: jaxlie.SE3, mean, covariance, valid, symmetries: jaxlie.SE3,
            symmetry_axis, symmetry_centre):
    """RMSE over a set of touches (T,) and its symmetry-aware value (:func:`closest_copy_square`);
    the first touch's pose errors."""
    per_touch = jax.vmap(moment_rmse)(mean, covariance, T_true, T_estimate)  # (T,), each touch its own cloud
    count = jnp.maximum(jnp.sum(valid), 1)
    rmse = jnp.sqrt(jnp.sum(jnp.where(valid, per_touch**2, 0.0)) / count)
    symmetric = jnp.sqrt(closest_copy_square(mean, covariance, valid, T_true, T_estimate, symmetries, symmetry_axis,
                                             symmetry_centre) / count)
    first_true, first_estimate = (jax.tree.map(lambda x: x[0], T) for T in (T_true, T_estimate))
    rotation = jnp.rad2deg(jnp.linalg.norm((first_true.inverse() @ first_estimate).rotation().log()))
    translation = jnp.linalg.norm(first_true.translation() - first_estimate.translation())
    return rmse, jnp.minimum(rmse, symmetric), translation, rotation


@functools.partial(top_level_jit, static_argnames=("method", "points_per_touch", "batch_size", "mesh"))
def _baseline_touches(view: LocalizationMap, touches: TestEpisodes, method, points_per_touch: int, batch_size: int,
                      mesh):
    """Touches localized alone by a baseline: ``touches`` holds one per item (leading axis T), as
    (T, 1, 1) episodes; (T,) errors, ``batch_size`` at a time on each device of ``mesh``."""
    def one(view, touch: TestEpisodes):
        take = lambda x: x[0, 0]  # noqa: E731
        T, m, c = jax.tree.map(take, touch.T_object_sensor), take(touch.cloud_mean), take(touch.cloud_covariance)
        estimate = baseline_estimate(jax.random.key(0), view, episode_touch(touch, 0, 0), method,
                                     points_per_touch=points_per_touch).T_object_sensor
        one_touch = lambda x: x[None]  # noqa: E731
        errors = _errors(jax.tree.map(one_touch, T), jax.tree.map(one_touch, estimate), m[None], c[None],
                         jnp.ones(1, bool), view.symmetries, view.symmetry_axis, view.symmetry_centre)
        nan = jnp.float32(jnp.nan)
        return (*errors, nan, nan, jnp.bool_(False))

    return over_batch(lambda view, touches: in_batches(lambda t: one(view, t), touches, batch_size), mesh)(
        view, touches)


@functools.partial(top_level_jit, static_argnames=("fingers", "alone"))
def _observe_episodes(view: LocalizationMap, episodes: TestEpisodes, beliefs: PoseBelief, fingers: int,
                      alone: bool):
    """(E, N) errors and probabilities of every episode's beliefs along its touch sequence
    (:func:`~tactojax.localize._episode_beliefs.sequence_order`): each over the touches it holds."""
    grasps = episodes.openings.shape[1]
    holds = jnp.asarray(sequence_touches(grasps, fingers, alone))  # (N, G * F)

    def episode(episode: TestEpisodes, beliefs: PoseBelief):
        # The sensor poses are given in the object frame, so a belief's world frame is the object's.
        T_true = jax.tree.map(lambda x: x[:, :fingers].reshape(-1, *x.shape[2:]), episode.T_object_sensor)
        mean = episode.cloud_mean[:, :fingers].reshape(-1, 3)
        covariance = episode.cloud_covariance[:, :fingers].reshape(-1, 3, 3)

        def observe(belief: PoseBelief, valid):
            # The first touch the belief holds leads: its pose errors are reported.
            order = jnp.argsort(~valid, stable=True)
            T_true_, mean_, covariance_, valid_ = jax.tree.map(lambda x: x[order], (T_true, mean, covariance, valid))
            errors = _errors(T_true_, belief.sensor_pose(T_true_), mean_, covariance_, valid_, view.symmetries,
                             view.symmetry_axis, view.symmetry_centre)
            # No touch with contact, no estimate: a failure (its placeholder pose, the identity,
            # is the truth here, the world frame being the object's).
            errors = tuple(jnp.where(belief.has_estimate, e, jnp.inf) for e in errors)
            return (*errors, belief.probability_within(), *belief.truth_scores(belief.T_world_reference))

        return jax.vmap(observe)(beliefs, holds)

    # One episode at a time: the credible sets compare every pair of hypotheses under every
    # symmetric copy, too much memory to hold for all episodes at once.
    return jax.lax.map(lambda pair: episode(*pair), (episodes, beliefs))


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

    The belief runs along every episode's touch sequence in one compiled program
    (:func:`~tactojax.localize._episode_beliefs.episode_beliefs`: the episode's touches fused in
    order, then every later grasp's first finger alone); its single-touch rows are the beliefs
    that hold one touch. The baselines localize every touch alone in a program of their own.
    Both shard their batch over ``devices`` (a mesh with one ``batch`` axis), each device
    localizing ``touch_batch_size`` touches (``episode_batch_size`` episodes) at once, vmapped;
    a program is called once per such batch on every device, which bounds the memory.

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
        touch_batch_size, episode_batch_size: a baseline's single touches and the belief's
            episodes a device localizes at once (vmapped; 1: one at a time). The results do not
            depend on the devices; they can move by rounding with these sizes, and the belief's
            discrete choices can follow (episodes go one at a time by default: the reference
            results).
        progress: show progress bars (per chunk).

    Returns:
        one :class:`EpisodeErrors` per method for single touches (``grasps`` 1, ``fingers`` 1;
        if ``single_touches``), then, for the belief, one per number of fused grasps with
        ``fingers`` fingers.
    """
    if fingers not in (1, 2) or episodes.heightmaps.shape[2] < fingers:
        raise ValueError(f"fingers must be 1 or 2 and the test set must have them (it has "
                         f"{episodes.heightmaps.shape[2]})")
    grasps = episodes.openings.shape[1]
    belief_rows = None
    if any(parse_method(name).kind == "belief" for name in methods):
        beliefs = episode_beliefs(view, episodes, fingers=fingers, alone=single_touches, settings=settings,
                                  devices=devices, batch_size=episode_batch_size, progress=progress)
        belief_rows = [np.asarray(x) for x in _observe_episodes(view, episodes, beliefs, fingers, single_touches)]
    mesh = batch_mesh(devices)
    touches = episodes.sensor_touches()
    count = touches.openings.shape[0]
    touch_batch_size = min(touch_batch_size, count)  # (a small test set: no padded batch)
    results = []
    for name in methods if single_touches else ():  # the touches: (E * G, 1, 1) episodes
        method = parse_method(name)
        if method.kind == "belief":  # (E, G) -> (E * G,), episode-major as the touches
            out = [x[:, alone_steps(grasps, fingers)].reshape(-1) for x in belief_rows]
        else:
            program = functools.partial(_baseline_touches, method=method, points_per_touch=points_per_touch,
                                        batch_size=touch_batch_size, mesh=mesh)
            with tqdm(total=count, desc=f"single touches ({method.name})", unit="touch",
                      disable=not progress) as bar:
                out = run_sharded(program, view, touches, mesh=mesh, bar=bar,
                                  per_device=touch_batch_size)
        results.append(EpisodeErrors(method.name, 1, 1, False, *out))
    if belief_rows is not None:
        for g, step in enumerate(fused_steps(grasps, fingers)):
            results.append(EpisodeErrors("belief", fingers, g + 1, True, *(x[:, step] for x in belief_rows)))
    return results
