"""Calibrating the belief on the map's own touches: the scales of its likelihood, fit by what happened.

A belief reports P(its best pose is within 2 mm of the truth). That number is only useful if it
is calibrated: of the beliefs that say 0.8, 80 % must be within 2 mm. The raw likelihood is not
(neighbouring pixels' errors are correlated, both fingers of a grasp and successive grasps are
not independent), so its scales (:class:`~tactojax.localize.BeliefCalibration`: a temperature
on the geometry, a weight on the appearance similarity, and an exponent that discounts the
evidence of several touches) are fit on *calibration episodes*: grasps of the map's own object
at known poses (``tactojax simulate OBJECT --protocol grasps`` with a seed of their own, or
recorded grasps of the real object), never the test set.

:func:`record_beliefs` runs the belief over the calibration episodes touch by touch and keeps,
after every touch, what the fit needs: every hypothesis's summed cues, which hypotheses are the
same pose (within 2 mm up to the object's symmetry) and which are the truth.
:func:`fit_calibration` then chooses the scales in three steps, each a grid search (the data are a
few hundred beliefs):

1. the likelihood's *shape*, which decides the best hypothesis: the appearance weight relative to
   the geometry's temperature, by the negative log-likelihood of the true pose (the belief's mass
   within 2 mm of it);
2. its *sharpness* at that shape: the temperature and the touch-count exponent, by the negative
   log-likelihood of what happened (the best hypothesis within 2 mm of the truth, or not) under
   the reported P(within 2 mm);
3. the probability that the search found the truth's mode at all, as a function of the touch
   count and the touches' contact area (:meth:`~tactojax.localize.BeliefCalibration.found_probability`;
   its growth with the area is the library's, fit once on the catalog objects), by the same
   loss (:func:`fit_found_probability`). Without it, one temperature has to serve beliefs of one
   touch, whose hypotheses often miss the truth altogether, and of six, whose rarely do: on the
   catalog objects' calibration grasps one-touch beliefs said 0.25-0.35 on average where 7-26 %
   were right, while six-touch beliefs were calibrated.

The second loss alone does not pin the shape down: a belief that leaves the appearance out is
less often right, but says so, and scores about as well (on the same calibration grasps, the
appearance weight it fit moved from 8 to 0 after a small change to the map's surface, its loss
within noise of the old fit's). The truth's likelihood rewards putting the mass on the truth; it
does not see the beliefs whose hypotheses all miss the truth, which the second step's loss does.

The shape is what decides the poses, and one map's calibration grasps (a few dozen episodes)
pin it down poorly: fit per map on the five catalog objects, it lost two or three episodes in
32 on the gum box and two on the marker. ``tactojax calibrate-belief`` therefore keeps the
default's shape (step 1 skipped: ``fit_calibration(records, shape=...)``) for maps whose
features come from the encoder the default was fit with, and fits only the sharpness and the
search term: the belief's poses stay exactly those of the default, only its confidence moves.
With ``--search-only`` (``fit_calibration(records, shape, search_only=True)``) it keeps the
default's sharpness too and fits only the search term, the one that differs most between objects
(after one touch 0.56 on the gum box, 0.98-1.00 on the other catalog objects).
"""

from __future__ import annotations

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from tactojax import _struct as struct
from tactojax.localize._belief import WITHIN_MM, BeliefSettings, PoseBelief, belief_terms, hypothesis_distances
from tactojax.localize._compile import top_level_jit
from tactojax.localize._episode_beliefs import TestEpisodes, episode_beliefs
from tactojax.localize._map import (DEFAULT_FOUND, FOUND_CONTACT_GROWTH, BeliefCalibration, LocalizationMap,
                                    found_log_odds)

TEMPERATURES = tuple(float(t) for t in np.geomspace(0.002, 1.0, 28))
"""Candidate temperatures of the geometric log-likelihood."""
APPEARANCE_WEIGHTS = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0)
"""Candidate weights of the appearance similarity (per touch)."""
FUSION_EXPONENTS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.5)
"""Candidate discounts of several touches' evidence."""
FOUND_OFFSETS = tuple(float(x) for x in np.arange(-3.0, 8.01, 0.25))
"""Candidate log-odds that the search found the truth's mode after one touch (8: it always does)."""
FOUND_SLOPES = tuple(float(x) for x in np.arange(0.0, 8.01, 0.25))
"""Candidate growths of those log-odds with the log of the touch count."""
FOUND_CONTACTS = tuple(float(x) for x in np.arange(0.0, 3.01, 0.25))
"""Candidate growths of those log-odds with the log of the touches' mean contact area, when it is
fit too (never negative: a larger contact never makes the search miss more often)."""


@struct.dataclass
class BeliefRecord:
    """What calibration needs of one belief (after one touch of a calibration episode)."""

    geometry: Float[Array, "M"]
    """Every hypothesis's geometric log-likelihood, summed over the belief's touches."""
    similarity: Float[Array, "M"]
    """Its appearance similarity, summed over the touches."""
    valid: Bool[Array, "M"]
    """Which hypothesis slots hold one."""
    touches: Int[Array, ""]
    """How many touches the belief holds."""
    contact_mm2: Float[Array, ""]
    """Their mean contact area, mm²."""
    same_pose: Bool[Array, "M M"]
    """Hypotheses within 2 mm of each other, up to the object's symmetry."""
    truth: Bool[Array, "M"]
    """Hypotheses within 2 mm of the true pose, up to the object's symmetry."""


@functools.partial(top_level_jit, static_argnames=("settings",))
def _records(view: LocalizationMap, beliefs: PoseBelief, settings: BeliefSettings) -> BeliefRecord:
    """(N,) what calibration needs of every belief of ``beliefs`` (leading axis N)."""

    def record(belief: PoseBelief) -> BeliefRecord:
        geometry, similarity = jax.vmap(lambda T: belief_terms(view, belief, T, settings))(belief.T_object_reference)
        same_pose = jax.vmap(lambda T: hypothesis_distances(belief, T, symmetric=True))(belief.T_object_reference)
        # The sensor poses are given in the object frame: the reference's world pose is the truth.
        truth = hypothesis_distances(belief, belief.T_world_reference, symmetric=True)
        valid = jnp.isfinite(belief.log_weights)
        return BeliefRecord(geometry=geometry, similarity=similarity, valid=valid, touches=belief.touches,
                            contact_mm2=belief.mean_contact_mm2,
                            same_pose=same_pose <= WITHIN_MM, truth=(truth <= WITHIN_MM) & valid)

    return jax.lax.map(record, beliefs)


def record_beliefs(
    view: LocalizationMap,
    episodes: TestEpisodes,
    *,
    fingers: int = 2,
    settings: BeliefSettings = BeliefSettings(),
    progress: bool = False,
) -> BeliefRecord:
    """Run the belief over calibration episodes and keep what :func:`fit_calibration` needs.

    Args:
        view: the map, with the scales the belief runs with (they decide which hypotheses it
            keeps; the map's own calibration, or the uncalibrated default).
        episodes: calibration grasps of the map's object (E episodes of G grasps).
        fingers: fingers per grasp (touches: G x fingers per episode, fused in order).
        settings: belief parameters.
        progress: show a progress bar.

    Returns:
        (E * (G * fingers + G - 1),) records, as numpy arrays: every episode's beliefs touch by
        touch, then each of its later grasps' first-finger touch alone.
    """
    beliefs = episode_beliefs(view, episodes, fingers=fingers, alone=True, settings=settings, progress=progress)
    per_episode = [jax.device_get(_records(view, jax.tree.map(lambda x: x[e], beliefs), settings))
                   for e in range(episodes.openings.shape[0])]
    return jax.tree.map(lambda *x: np.concatenate(x), *per_episode)


def _posterior(records: BeliefRecord, calibration: BeliefCalibration) -> tuple[np.ndarray, np.ndarray]:
    """(N, M) every belief's hypothesis weights under ``calibration`` and (N,) its best hypothesis."""
    temperature, appearance, exponent = (float(x) for x in (calibration.temperature, calibration.appearance,
                                                            calibration.fusion_exponent))
    score = temperature * records.geometry + appearance * records.similarity
    score = np.where(records.valid, score, -np.inf)
    scaled = np.maximum(records.touches, 1)[:, None] ** -exponent * score
    scaled = scaled - scaled.max(axis=1, keepdims=True)
    weights = np.where(records.valid, np.exp(scaled), 0.0)
    weights = weights / np.maximum(weights.sum(axis=1, keepdims=True), 1e-30)
    return weights, np.argmax(score, axis=1)


def _mass_near_best(records: BeliefRecord, calibration: BeliefCalibration) -> tuple[np.ndarray, np.ndarray]:
    """(N,) the hypotheses' mass within 2 mm of the best under ``calibration``'s scales, and (N,)
    whether the best was within 2 mm of the truth."""
    weights, best = _posterior(records, calibration)
    rows = np.arange(len(best))
    return np.sum(np.where(records.same_pose[rows, best], weights, 0.0), axis=1), records.truth[rows, best]


def _found(calibration: BeliefCalibration, records: BeliefRecord) -> np.ndarray:
    """(N,) :meth:`~tactojax.localize.BeliefCalibration.found_probability` of every record's
    belief, in numpy."""
    log_odds = found_log_odds(float(calibration.found_offset), float(calibration.found_slope),
                              float(calibration.found_contact), records.touches, records.contact_mm2)
    return 1.0 / (1.0 + np.exp(-log_odds))


def predict_within(records: BeliefRecord, calibration: BeliefCalibration) -> tuple[np.ndarray, np.ndarray]:
    """(N,) P(best within 2 mm) that the beliefs of ``records`` report under ``calibration``
    (:meth:`~tactojax.localize.PoseBelief.probability_within`), and (N,) whether their best
    hypothesis was within 2 mm of the truth (numpy)."""
    near, happened = _mass_near_best(records, calibration)
    return near * _found(calibration, records), happened


def truth_probability(records: BeliefRecord, calibration: BeliefCalibration) -> np.ndarray:
    """(N,) the mass the beliefs of ``records`` put within 2 mm of the true pose under ``calibration``."""
    weights, _ = _posterior(records, calibration)
    return np.sum(np.where(records.truth, weights, 0.0), axis=1)


PROBABILITY_FLOOR = 1e-4
"""Probabilities are clipped to [floor, 1 - floor] in the losses: one belief cannot dominate a fit."""


def log_losses(probability: np.ndarray, happened: np.ndarray, floor: float = PROBABILITY_FLOOR) -> np.ndarray:
    """(N,) negative log-likelihood of what happened (bool) under each predicted probability,
    clipped to ``[floor, 1 - floor]``."""
    p = np.clip(np.asarray(probability, np.float64), floor, 1 - floor)
    return -np.where(np.asarray(happened, bool), np.log(p), np.log1p(-p))


def within_log_loss(probability: np.ndarray, happened: np.ndarray) -> float:
    """Mean negative log-likelihood of what happened under the predicted probabilities."""
    return float(np.mean(log_losses(probability, happened)))


def truth_log_loss(mass: np.ndarray) -> float:
    """Mean negative log of the beliefs' mass within 2 mm of the truth (:func:`truth_probability`)."""
    return float(-np.mean(np.log(np.clip(mass, PROBABILITY_FLOOR, 1.0))))


def _scales(temperature: float, appearance: float, exponent: float) -> BeliefCalibration:
    """The scales as numpy scalars, the search taken as complete (the dataclass's own default:
    the steps before the last fit the scales without it)."""
    return BeliefCalibration(temperature=np.float32(temperature), appearance=np.float32(appearance),
                             fusion_exponent=np.float32(exponent))


def fit_found_probability(records: BeliefRecord, calibration: BeliefCalibration, *,
                          contact: float | None = FOUND_CONTACT_GROWTH) -> BeliefCalibration:
    """``calibration`` with the probability that the search found the truth's mode
    (:meth:`~tactojax.localize.BeliefCalibration.found_probability`) fit on ``records`` (numpy,
    e.g. several maps' pooled): the offset and slope of the grid :data:`FOUND_OFFSETS` x
    :data:`FOUND_SLOPES` that minimise :func:`within_log_loss` at ``calibration``'s scales, with
    the growth with the contact area fixed at ``contact`` (default: the library's
    :data:`~tactojax.localize._map.FOUND_CONTACT_GROWTH`; 0: the term as it was before the
    contact area entered it), or, with ``contact=None``, fit too over :data:`FOUND_CONTACTS` (the
    first of equal losses: the smallest; it needs calibration grasps with many small touches)."""
    near, happened = _mass_near_best(records, calibration)
    grid = np.array(list(itertools.product(FOUND_OFFSETS, FOUND_SLOPES)))  # (K, 2)
    best_loss, best = np.inf, None
    for growth in FOUND_CONTACTS if contact is None else (float(contact),):  # one at a time: (K, N) arrays
        log_odds = found_log_odds(grid[:, :1], grid[:, 1:], growth, records.touches[None], records.contact_mm2[None])
        losses = np.mean(log_losses(near[None] / (1.0 + np.exp(-log_odds)), happened[None]), axis=1)
        if losses.min() < best_loss:
            best_loss, best = losses.min(), (*grid[int(np.argmin(losses))], growth)
    offset, slope, growth = best
    return calibration.replace(found_offset=np.float32(offset), found_slope=np.float32(slope),
                               found_contact=np.float32(growth))


def fit_calibration(records: BeliefRecord, shape: BeliefCalibration | None = None, *,
                    search_only: bool = False) -> tuple[BeliefCalibration, dict]:
    """The belief's scales, fit on calibration beliefs in three steps (see the module docstring).

    1. The ratio of the appearance weight to the temperature: the one of the grid
       :data:`TEMPERATURES` x :data:`APPEARANCE_WEIGHTS` x :data:`FUSION_EXPONENTS` that minimises
       :func:`truth_log_loss` (skipped with ``shape``).
    2. At that ratio, the temperature and the exponent (:data:`TEMPERATURES` x
       :data:`FUSION_EXPONENTS`) that minimise :func:`within_log_loss`.
    3. At those scales, the probability that the search found the truth's mode
       (:func:`fit_found_probability`).

    Args:
        records: the calibration beliefs (:func:`record_beliefs`).
        shape: keep this calibration's ratio of the appearance weight to the temperature
            instead of fitting it (None: fit it). Within one update every hypothesis's score is
            then scaled by one positive factor, so the belief keeps, refines and ranks the same
            hypotheses as under ``shape``: the fit changes how sure the belief says it is, never
            its poses (one map's few dozen calibration episodes are too few to move the ratio
            without losing episodes: docs/localization.md).
        search_only: keep ``shape``'s temperature and exponent too (step 2 skipped): fit only
            the probability that the search found the truth's mode. That term differs most
            between objects (a box's single touch leaves more poses than 64 hypotheses cover),
            and two parameters are what a few dozen calibration episodes pin down: on the
            catalog objects' 32 episodes a fit of the temperature and exponent as well moved
            the screwdriver's and the marker's calibration gaps the wrong way on new grasps
            (docs/localization.md).

    Returns:
        the fitted :class:`BeliefCalibration` and a JSON-ready report (``loss``: the within log
        loss, ``truth_loss``: the truth's, ``accuracy``: the share of best hypotheses within
        2 mm, ``beliefs``: how many records, ``contact_mm2``: the median contact area of the
        one-touch beliefs (the object's typical touch, mm²; None without any), and the scales).

    Raises:
        ValueError: no record holds a hypothesis (nothing to fit), or ``search_only`` without
            ``shape``.
    """
    if search_only and shape is None:
        raise ValueError("search_only keeps the scales of `shape`: pass the calibration to keep")
    usable = records.valid.any(axis=1)
    if not usable.any():
        raise ValueError("no calibration touch produced a hypothesis: the calibration grasps do not touch the map")
    records = jax.tree.map(lambda x: x[usable], records)
    if shape is None:
        grid = itertools.product(TEMPERATURES, APPEARANCE_WEIGHTS, FUSION_EXPONENTS)
        shape = min((_scales(*scales) for scales in grid),
                    key=lambda scales: truth_log_loss(truth_probability(records, scales)))
    if search_only:
        fitted = _scales(float(shape.temperature), float(shape.appearance), float(shape.fusion_exponent))
    else:
        ratio = float(shape.appearance) / float(shape.temperature)
        fitted = min((_scales(temperature, ratio * temperature, exponent)
                      for temperature, exponent in itertools.product(TEMPERATURES, FUSION_EXPONENTS)),
                     key=lambda scales: within_log_loss(*predict_within(records, scales)))
    fitted = fit_found_probability(records, fitted)
    probability, happened = predict_within(records, fitted)
    report = {"loss": within_log_loss(probability, happened),
              "truth_loss": truth_log_loss(truth_probability(records, fitted)),
              "accuracy": float(np.mean(happened)), "beliefs": int(usable.sum()),
              "contact_mm2": float(np.median(records.contact_mm2[records.touches == 1]))
              if np.any(records.touches == 1) else None}
    fitted = jax.tree.map(jnp.float32, fitted)
    return fitted, {**report, **calibration_to_json(fitted)}


CALIBRATION_FIELDS = ("temperature", "appearance", "fusion_exponent", "found_offset", "found_slope", "found_contact")
"""What a stored fit holds, in order."""


def calibration_to_json(calibration: BeliefCalibration) -> dict:
    """The calibration as a JSON-ready dict (what a map's header stores)."""
    return {name: float(getattr(calibration, name)) for name in CALIBRATION_FIELDS}


def calibration_from_json(values: dict) -> BeliefCalibration:
    """The inverse of :func:`calibration_to_json`. A fit stored before the search's miss rate was
    fit (no ``found_offset``) takes the default's (:data:`~tactojax.localize._map.DEFAULT_FOUND`);
    one stored before its contact term, a contact growth of 0 (the term as it was fit)."""
    if "found_offset" not in values:  # stored before the search's miss rate was fit
        values = {**values, **DEFAULT_FOUND}
    values = {"found_contact": 0.0, **values}  # stored before the contact area entered it: fit without it
    return BeliefCalibration(**{name: jnp.float32(values[name]) for name in CALIBRATION_FIELDS})
