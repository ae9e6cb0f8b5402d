"""Tactile localization and identification (paper sections VI-VII, and beyond). Pure JAX.

The library's answer is a pose belief: :func:`localize` turns one or several touches of an
object (with their sensor poses, from the robot's kinematics) into a :class:`PoseBelief` over
where it is, with a calibrated P(within 2 mm); :class:`Localizer` does the same from raw
camera frames at control-loop rate, over several objects, and :class:`Tracker` follows the
object between frames from there. The paper's one-touch methods (``random``, ``cti``,
``cti-icp-N``) remain as baselines (:func:`localize_baseline`).

A typical session::

    view = tactojax.io.load_localization_map("scissors.npz")   # once per object (calibration included)
    touches = [touch_from_image(model, encoder, image, opening) for image, opening in frames]
    belief = localize(view, touches, T_world_sensors)           # the robot's kinematics
    belief.T_world_object, belief.probability_within(2.0)
"""

from tactojax.localize._active import ActiveSettings as ActiveSettings
from tactojax.localize._active import belief_error as belief_error
from tactojax.localize._active import GraspRanking as GraspRanking
from tactojax.localize._active import next_grasp as next_grasp
from tactojax.localize._active import propose_grasps as propose_grasps
from tactojax.localize._active import should_stop as should_stop
from tactojax.localize._baselines import PAPER_METHODS as PAPER_METHODS
from tactojax.localize._baselines import localize_baseline as localize_baseline
from tactojax.localize._baselines import estimate_pose as estimate_pose
from tactojax.localize._evaluate import cloud_moments as cloud_moments
from tactojax.localize._evaluate import moment_rmse as moment_rmse
from tactojax.localize._evaluate import oracle_imprints as oracle_imprints
from tactojax.localize._map import map_touch as map_touch
from tactojax.localize._points import POINTS_PER_TOUCH as POINTS_PER_TOUCH
from tactojax.localize._points import contact_points as contact_points
from tactojax.localize._retrieval import MAX_OPENING_DIFFERENCE_MM as MAX_OPENING_DIFFERENCE_MM
from tactojax.localize._retrieval import closest_imprints as closest_imprints
from tactojax.localize._belief import WITHIN_MM as WITHIN_MM
from tactojax.localize._belief import BeliefSettings as BeliefSettings
from tactojax.localize._belief import PoseBelief as PoseBelief
from tactojax.localize._belief import empty_belief as empty_belief
from tactojax.localize._belief import update_belief as update_belief
from tactojax.localize._calibrate import calibration_from_json as calibration_from_json
from tactojax.localize._calibrate import calibration_to_json as calibration_to_json
from tactojax.localize._calibrate import fit_calibration as fit_calibration
from tactojax.localize._calibrate import record_beliefs as record_beliefs
from tactojax.localize._evaluate import LocalizationErrors as LocalizationErrors
from tactojax.localize._evaluate import evaluate_localization as evaluate_localization
from tactojax.localize._evaluate import map_size_study as map_size_study
from tactojax.localize._icp import IcpSettings as IcpSettings
from tactojax.localize._identify import IdentificationResult as IdentificationResult
from tactojax.localize._identify import MapLibrary as MapLibrary
from tactojax.localize._identify import evaluate_identification as evaluate_identification
from tactojax.localize._identify import identify as identify
from tactojax.localize._identify_episodes import identify_episodes as identify_episodes
from tactojax.localize._identify_episodes import shared_calibration as shared_calibration
from tactojax.localize._localize import localize as localize
from tactojax.localize._localizer import LiveEstimate as LiveEstimate
from tactojax.localize._localizer import LiveSettings as LiveSettings
from tactojax.localize._localizer import Localizer as Localizer
from tactojax.localize._localizer import touch_from_image as touch_from_image
from tactojax.localize._map import BeliefCalibration as BeliefCalibration
from tactojax.localize._map import LocalizationMap as LocalizationMap
from tactojax.localize._map import Touch as Touch
from tactojax.localize._map import shared_shapes as shared_shapes
from tactojax.localize._new_grasps import EpisodeErrors as EpisodeErrors
from tactojax.localize._new_grasps import TestEpisodes as TestEpisodes
from tactojax.localize._new_grasps import evaluate_new_grasps as evaluate_new_grasps
from tactojax.localize._pose import PoseEstimate as PoseEstimate
from tactojax.localize._predict_touch import MarchingGrid as MarchingGrid
from tactojax.localize._predict_touch import PredictedGrasp as PredictedGrasp
from tactojax.localize._predict_touch import PredictionSettings as PredictionSettings
from tactojax.localize._predict_touch import map_marching_grid as map_marching_grid
from tactojax.localize._predict_touch import predict_grasp as predict_grasp
from tactojax.localize._test_episodes import load_test_episodes as load_test_episodes
from tactojax.localize._tracker import Tracker as Tracker
from tactojax.localize._tracker import TrackingSettings as TrackingSettings

__all__ = [
    "should_stop",
    "belief_error",
    "propose_grasps",
    "predict_grasp",
    "next_grasp",
    "map_marching_grid",
    "PredictionSettings",
    "PredictedGrasp",
    "MarchingGrid",
    "GraspRanking",
    "ActiveSettings",
    "PAPER_METHODS",
    "WITHIN_MM",
    "BeliefCalibration",
    "BeliefSettings",
    "EpisodeErrors",
    "IcpSettings",
    "IdentificationResult",
    "LiveEstimate",
    "LiveSettings",
    "LocalizationErrors",
    "LocalizationMap",
    "Localizer",
    "MapLibrary",
    "PoseBelief",
    "PoseEstimate",
    "TestEpisodes",
    "Touch",
    "Tracker",
    "TrackingSettings",
    "calibration_from_json",
    "calibration_to_json",
    "empty_belief",
    "evaluate_identification",
    "evaluate_localization",
    "evaluate_new_grasps",
    "fit_calibration",
    "identify",
    "identify_episodes",
    "load_test_episodes",
    "localize",
    "localize_baseline",
    "map_size_study",
    "record_beliefs",
    "shared_calibration",
    "shared_shapes",
    "touch_from_image",
    "update_belief",
    "estimate_pose",
    "cloud_moments",
    "moment_rmse",
    "oracle_imprints",
    "map_touch",
    "POINTS_PER_TOUCH",
    "contact_points",
    "MAX_OPENING_DIFFERENCE_MM",
    "closest_imprints",
]
