"""Which object is in the hand, from the grasps of an episode: object and pose in one belief.

Every map of the catalog keeps its own pose belief over the same touches, all with *one*
calibration so that their likelihoods compare; P(object) after k grasps is the softmax, over the
maps, of each belief's log evidence (the log of its hypotheses' summed likelihoods, a uniform
prior over objects). The same likelihood that weighs poses within a map weighs the maps.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from tactojax.localize._belief import BeliefSettings
from tactojax.localize._episode_beliefs import TestEpisodes, episode_beliefs, fused_steps
from tactojax.localize._map import BeliefCalibration, LocalizationMap, shared_shapes


def shared_calibration(calibrations: list[BeliefCalibration | None]) -> BeliefCalibration:
    """One calibration for beliefs that must compare: the element-wise median of the maps' own
    (the uncalibrated default where none has one)."""
    fitted = [c for c in calibrations if c is not None]
    if not fitted:
        return BeliefCalibration.default()
    return jax.tree.map(lambda *x: jnp.float32(np.median(np.stack(x))), *fitted)


def identify_episodes(
    maps: list[LocalizationMap],
    episodes: TestEpisodes,
    *,
    fingers: int = 2,
    calibration: BeliefCalibration | None = None,
    settings: BeliefSettings = BeliefSettings(),
    progress: bool = False,
) -> np.ndarray:
    """P(object) after each grasp of every episode, over a catalog of maps.

    Args:
        maps: every object's map.
        episodes: E episodes of G grasps (the only kinematics used: poses relative to the first touch).
        fingers: fingers fused per grasp.
        calibration: the one calibration every belief runs with (default: uncalibrated; see
            :func:`shared_calibration`).
        settings: belief parameters.
        progress: show a progress bar.

    Returns:
        (E, G, M) probabilities of the M objects after 1..G grasps (a uniform prior).
    """
    calibration = BeliefCalibration.default() if calibration is None else calibration
    grasps = episodes.openings.shape[1]
    # One shape for every map: the belief compiles once for the catalog.
    views = shared_shapes([view.replace(calibration=calibration) for view in maps])
    log_evidence = np.stack([
        episode_beliefs(view, episodes, fingers=fingers, settings=settings).log_evidence[:, fused_steps(grasps, fingers)]
        for view in tqdm(views, desc="beliefs (map)", disable=not progress)], axis=-1)
    probabilities = object_probabilities(log_evidence)
    return np.where(probabilities.sum(axis=-1, keepdims=True) > 0, probabilities, 1.0 / len(maps))


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
