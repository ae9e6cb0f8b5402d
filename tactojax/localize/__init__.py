"""Tactile localization and identification (paper sections VI-VII, and beyond). Pure JAX.

The library's answer is a pose belief: :func:`localize` turns one or several touches of an
object (with their sensor poses, from the robot's kinematics) into a :class:`PoseBelief` over
where it is, with a calibrated P(within 2 mm); :class:`Localizer` does the same from raw
camera frames at control-loop rate, over several objects, and :class:`Tracker` follows the
object between frames from there. The paper's one-touch methods (``random``, ``cti``,
``cti-icp-N``, and identification by the closest imprint) remain as baselines
(:mod:`tactojax.localize.baselines`). The evaluation protocols
and metrics are in :mod:`tactojax.localize.evaluation`, and the choice of the next grasp in
:mod:`tactojax.localize.active`.

A typical session::

    view = tactojax.io.load_localization_map("scissors.npz")   # once per object (calibration included)
    touches = [touch_from_image(model, encoder, image, opening) for image, opening in frames]
    belief = localize(view, touches, T_world_sensors)           # the robot's kinematics
    belief.T_world_object, belief.probability_within(2.0)
"""

from tactojax._moved import moved_names
from tactojax.localize._belief import BeliefDigest as BeliefDigest
from tactojax.localize._belief import belief_digest as belief_digest
from tactojax.localize._belief import BeliefSettings as BeliefSettings
from tactojax.localize._belief import empty_belief as empty_belief
from tactojax.localize._belief import PoseBelief as PoseBelief
from tactojax.localize._belief import update_belief as update_belief
from tactojax.localize._belief import WITHIN_MM as WITHIN_MM
from tactojax.localize._calibrate import calibration_from_json as calibration_from_json
from tactojax.localize._calibrate import calibration_to_json as calibration_to_json
from tactojax.localize._calibrate import fit_calibration as fit_calibration
from tactojax.localize._compile import COMPILER_OPTIONS as COMPILER_OPTIONS
from tactojax.localize._identify_episodes import shared_calibration as shared_calibration
from tactojax.localize._localize import localize as localize
from tactojax.localize._localizer import LiveEstimate as LiveEstimate
from tactojax.localize._localizer import LiveSettings as LiveSettings
from tactojax.localize._localizer import Localizer as Localizer
from tactojax.localize._localizer import touch_from_image as touch_from_image
from tactojax.localize._map import BeliefCalibration as BeliefCalibration
from tactojax.localize._map import LocalizationMap as LocalizationMap
from tactojax.localize._map import Touch as Touch
from tactojax.localize._stacked_maps import StackedMaps as StackedMaps
from tactojax.localize._surface import MapSurface as MapSurface
from tactojax.localize._surface import SurfaceSettings as SurfaceSettings
from tactojax.localize._surface import build_map_surface as build_map_surface
from tactojax.localize._tracker import Tracker as Tracker
from tactojax.localize._tracker import TrackingSettings as TrackingSettings

__all__ = [
    "COMPILER_OPTIONS",
    "WITHIN_MM",
    "BeliefCalibration",
    "BeliefDigest",
    "BeliefSettings",
    "LiveEstimate",
    "LiveSettings",
    "LocalizationMap",
    "Localizer",
    "MapSurface",
    "PoseBelief",
    "StackedMaps",
    "SurfaceSettings",
    "Touch",
    "Tracker",
    "TrackingSettings",
    "belief_digest",
    "build_map_surface",
    "calibration_from_json",
    "calibration_to_json",
    "empty_belief",
    "fit_calibration",
    "localize",
    "shared_calibration",
    "touch_from_image",
    "update_belief",
]

_MOVED = {
    "ActiveSettings": "tactojax.localize.active",
    "EpisodeErrors": "tactojax.localize.evaluation",
    "GraspRanking": "tactojax.localize.active",
    "IcpSettings": "tactojax.localize.baselines",
    "IdentificationResult": "tactojax.localize.evaluation",
    "LocalizationErrors": "tactojax.localize.evaluation",
    "MAX_OPENING_DIFFERENCE_MM": "tactojax.localize.baselines",
    "MapLibrary": "tactojax.localize.baselines",
    "MarchingGrid": "tactojax.localize.active",
    "PAPER_METHODS": "tactojax.localize.baselines",
    "POINTS_PER_TOUCH": "tactojax.localize.baselines",
    "PoseEstimate": "tactojax.localize.baselines",
    "PredictedGrasp": "tactojax.localize.active",
    "PredictionSettings": "tactojax.localize.active",
    "TestEpisodes": "tactojax.localize.evaluation",
    "belief_error": "tactojax.localize.evaluation",
    "closest_imprints": "tactojax.localize.baselines",
    "cloud_moments": "tactojax.localize.evaluation",
    "contact_points": "tactojax.localize.baselines",
    "estimate_pose": "tactojax.localize.baselines",
    "evaluate_identification": "tactojax.localize.evaluation",
    "evaluate_localization": "tactojax.localize.evaluation",
    "evaluate_new_grasps": "tactojax.localize.evaluation",
    "identify": "tactojax.localize.baselines",
    "identify_episodes": "tactojax.localize.evaluation",
    "load_test_episodes": "tactojax.localize.evaluation",
    "localize_baseline": "tactojax.localize.baselines",
    "map_marching_grid": "tactojax.localize.active",
    "map_size_study": "tactojax.localize.evaluation",
    "map_touch": "tactojax.localize.evaluation",
    "moment_rmse": "tactojax.localize.evaluation",
    "next_grasp": "tactojax.localize.active",
    "oracle_imprints": "tactojax.localize.evaluation",
    "predict_grasp": "tactojax.localize.active",
    "propose_grasps": "tactojax.localize.active",
    "record_beliefs": "tactojax.localize.evaluation",
    "should_stop": "tactojax.localize.active",
}
"""Names that moved to a public submodule; the old path warns until the next release."""


__getattr__ = moved_names(__name__, _MOVED)
