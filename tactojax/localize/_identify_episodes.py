"""Which object is in the hand, from the grasps of an episode: object and pose in one belief.

Every map of the catalog keeps its own pose belief over the same touches, all with *one*
calibration so that their likelihoods compare; P(object) after k grasps is the softmax, over the
maps, of each belief's log evidence (the log of its hypotheses' summed likelihoods, a uniform
prior over objects). The same likelihood that weighs poses within a map weighs the maps.

A map stops being weighed once its object is all but ruled out: after every grasp, the least
probable maps whose P(object) together is at most ``object_tolerance`` are dropped until the
object is released (:func:`likely_objects`). The grasps after the first then cost the beliefs of
the objects still in play, not of the whole catalog, and P(object) loses at most that much per
grasp. The live :class:`~tactojax.localize.Localizer` prunes the same way.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from tactojax.localize._belief import BeliefSettings
from tactojax.localize._episode_beliefs import TestEpisodes, episode_beliefs, fused_steps
from tactojax.localize._map import BeliefCalibration, LocalizationMap
from tactojax.localize._stacked_maps import StackedMaps

OBJECT_TOLERANCE = 1e-5
"""P(object) that a grasp may drop: the least probable maps that together hold at most this much
are not weighed again until the object is released (0: every map stays). P(object) is
overconfident in its tail: after one grasp the true object's came as low as 7e-5 (79 maps, 80
episodes) and 4e-4 (5 maps, 160 episodes), and 1e-3 then dropped the truth in 2.5 % and 0.6 % of
the episodes; 1e-5, an order of magnitude below, dropped it in none (docs/localization.md)."""


def shared_calibration(calibrations: list[BeliefCalibration | None]) -> BeliefCalibration:
    """One calibration for beliefs that must compare: the element-wise median of the maps' own
    (the uncalibrated default where none has one)."""
    fitted = [c for c in calibrations if c is not None]
    if not fitted:
        return BeliefCalibration.default()
    return jax.tree.map(lambda *x: jnp.float32(np.median(np.stack(x))), *fitted)


def identify_episodes(
    maps: StackedMaps | list[LocalizationMap],
    episodes: TestEpisodes,
    *,
    fingers: int = 2,
    calibration: BeliefCalibration | None = None,
    settings: BeliefSettings = BeliefSettings(),
    object_tolerance: float = OBJECT_TOLERANCE,
    progress: bool = False,
) -> np.ndarray:
    """P(object) after each grasp of every episode, over a catalog of maps.

    Args:
        maps: every object's map (a :class:`~tactojax.localize.StackedMaps`, or the maps to stack).
        episodes: E episodes of G grasps (the only kinematics used: poses relative to the first touch).
        fingers: fingers fused per grasp.
        calibration: the one calibration every belief runs with (default: uncalibrated; see
            :func:`shared_calibration`).
        settings: belief parameters.
        object_tolerance: P(object) a grasp may drop (:func:`likely_objects`), as the live
            localizer does (0: every map stays). Every map's belief runs all the same here: the
            maps dropped are those the live loop would no longer update.
        progress: show a progress bar.

    Returns:
        (E, G, M) probabilities of the M objects after 1..G grasps (a uniform prior; 0 for a
        map dropped after an earlier grasp).
    """
    calibration = BeliefCalibration.default() if calibration is None else calibration
    grasps = episodes.openings.shape[1]
    # Every map's window of the stack has one shape: the belief compiles once for the catalog.
    stack = (maps if isinstance(maps, StackedMaps) else StackedMaps.from_maps(maps)).with_calibration(calibration)
    log_evidence = np.stack([
        episode_beliefs(stack.window(m), episodes, fingers=fingers,
                        settings=settings).log_evidence[:, fused_steps(grasps, fingers)]
        for m in tqdm(range(len(stack)), desc="beliefs (map)", disable=not progress)], axis=-1)
    probabilities = pruned_probabilities(log_evidence, object_tolerance)
    return np.where(probabilities.sum(axis=-1, keepdims=True) > 0, probabilities, 1.0 / len(stack))


def likely_objects(probabilities, tolerance: float = OBJECT_TOLERANCE) -> np.ndarray:
    """(..., M) which maps stay in play after a grasp: all but the least probable ones whose
    P(object) (over the last axis) sums to at most ``tolerance``. Every map stays where
    ``tolerance`` is 0 or no map has any probability (no map explains the touches)."""
    probabilities = np.asarray(probabilities, np.float64)
    if not 0.0 <= tolerance < 1.0:  # 1 or more would drop every map
        raise ValueError(f"object_tolerance must be in [0, 1), got {tolerance}")
    order = np.argsort(probabilities, axis=-1, kind="stable")  # least probable first
    dropped_sorted = np.cumsum(np.take_along_axis(probabilities, order, axis=-1), axis=-1) <= tolerance
    dropped = np.zeros(probabilities.shape, bool)
    np.put_along_axis(dropped, order, dropped_sorted, axis=-1)
    nothing = ~np.any(probabilities > 0, axis=-1, keepdims=True)
    return ~dropped | nothing | (tolerance == 0)


def maps_in_play(probabilities, tolerance: float = OBJECT_TOLERANCE) -> np.ndarray:
    """(..., G, M) which maps each of G grasps updates, from the P(object) after every grasp
    (:func:`pruned_probabilities`): every map at the first, then those :func:`likely_objects`
    kept after each grasp before it."""
    probabilities = np.asarray(probabilities)
    kept = likely_objects(probabilities[..., :-1, :], tolerance)
    in_play = np.concatenate([np.ones_like(kept[..., :1, :]), kept], axis=-2)
    return np.logical_and.accumulate(in_play, axis=-2)


def pruned_probabilities(log_evidence, tolerance: float = OBJECT_TOLERANCE) -> np.ndarray:
    """(..., G, M) P(object) after each of G grasps from the maps' log evidence after each,
    a map left out from the grasp after the one that dropped it (:func:`likely_objects`)."""
    log_evidence = np.asarray(log_evidence, np.float64)
    in_play = np.ones(log_evidence[..., 0, :].shape, bool)
    probabilities = []
    for g in range(log_evidence.shape[-2]):
        probabilities.append(object_probabilities(np.where(in_play, log_evidence[..., g, :], -np.inf)))
        in_play = in_play & likely_objects(probabilities[-1], tolerance)
    return np.stack(probabilities, axis=-2)


def object_probabilities(log_evidence) -> np.ndarray:
    """(..., M) P(object) over M maps whose beliefs share one calibration: the softmax of their
    log evidence over the last axis (a uniform prior). All zero where no map explains the
    touches at all (every log evidence -inf)."""
    log_evidence = np.asarray(log_evidence, np.float64)
    finite = np.isfinite(log_evidence)
    top = np.max(np.where(finite, log_evidence, -np.inf), axis=-1, keepdims=True)
    weights = np.where(finite, np.exp(log_evidence - np.where(np.isfinite(top), top, 0.0)), 0.0)
    total = weights.sum(axis=-1, keepdims=True)
    return np.where(total > 0, weights / np.maximum(total, 1e-300), 0.0)
