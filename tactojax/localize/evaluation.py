"""Evaluation protocols and metrics of localization and identification (paper section VIII).

Leave-one-out on a map's own imprints (:func:`evaluate_localization`, the paper's Table III),
*new* grasps that are not in the map (:func:`evaluate_new_grasps`, the headline; the beliefs
along each episode's touches: :func:`episode_beliefs`), the map-size
study, identification among maps, the error metric: the RMSE between a touch's true contact
cloud at its true and its estimated pose (:func:`moment_rmse`, from the cloud's moments), and
two runs on one test set compared episode by episode (:func:`compare_evaluations`).
"""

from tactojax.localize._active import belief_error as belief_error
from tactojax.localize._belief import truth_against_best as truth_against_best
from tactojax.localize._calibrate import fit_found_probability as fit_found_probability
from tactojax.localize._calibrate import predict_within as predict_within
from tactojax.localize._calibrate import record_beliefs as record_beliefs
from tactojax.localize._calibrate import within_log_loss as within_log_loss
from tactojax.localize._compare import compare_evaluations as compare_evaluations
from tactojax.localize._compare import format_p as format_p
from tactojax.localize._compare import paired_log_loss as paired_log_loss
from tactojax.localize._compare import paired_shares as paired_shares
from tactojax.localize._compare import share_interval as share_interval
from tactojax.localize._episode_beliefs import TestEpisodes as TestEpisodes
from tactojax.localize._episode_beliefs import episode_beliefs as episode_beliefs
from tactojax.localize._episode_beliefs import sequence_order as sequence_order
from tactojax.localize._evaluate import LEAVE_ONE_OUT_GRID as LEAVE_ONE_OUT_GRID
from tactojax.localize._evaluate import LocalizationErrors as LocalizationErrors
from tactojax.localize._evaluate import cloud_moments as cloud_moments
from tactojax.localize._evaluate import evaluate_localization as evaluate_localization
from tactojax.localize._evaluate import map_size_study as map_size_study
from tactojax.localize._evaluate import moment_rmse as moment_rmse
from tactojax.localize._evaluate import oracle_imprints as oracle_imprints
from tactojax.localize._identify import IdentificationResult as IdentificationResult
from tactojax.localize._identify import evaluate_identification as evaluate_identification
from tactojax.localize._identify_episodes import identify_episodes as identify_episodes
from tactojax.localize._identify_episodes import likely_objects as likely_objects
from tactojax.localize._identify_episodes import maps_in_play as maps_in_play
from tactojax.localize._map import map_touch as map_touch
from tactojax.localize._new_grasps import EpisodeErrors as EpisodeErrors
from tactojax.localize._new_grasps import calibration as calibration
from tactojax.localize._new_grasps import calibration_gap as calibration_gap
from tactojax.localize._new_grasps import evaluate_new_grasps as evaluate_new_grasps
from tactojax.localize._test_episodes import load_test_episodes as load_test_episodes

__all__ = [
    "EpisodeErrors",
    "IdentificationResult",
    "LEAVE_ONE_OUT_GRID",
    "LocalizationErrors",
    "TestEpisodes",
    "belief_error",
    "calibration",
    "calibration_gap",
    "cloud_moments",
    "compare_evaluations",
    "episode_beliefs",
    "evaluate_identification",
    "evaluate_localization",
    "evaluate_new_grasps",
    "fit_found_probability",
    "format_p",
    "identify_episodes",
    "likely_objects",
    "load_test_episodes",
    "map_size_study",
    "map_touch",
    "maps_in_play",
    "moment_rmse",
    "oracle_imprints",
    "paired_log_loss",
    "paired_shares",
    "predict_within",
    "record_beliefs",
    "sequence_order",
    "share_interval",
    "truth_against_best",
    "within_log_loss",
]
