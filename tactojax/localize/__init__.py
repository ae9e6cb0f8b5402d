"""Tactile localization (paper section VI) and identification (section VII). Pure JAX.

A query imprint (predicted heightmap, mask, features, opening) is matched to an object's
tactile map: retrieval of the most similar stored imprints (CTI), then point-to-plane ICP
against them, with correspondences found by projecting into the stored heightmaps. Methods:
``random``, ``cti``, ``cti-icp-N`` (the paper's), ``cti-icp-multistart-N`` and
``cti-search-N`` (hypotheses around the retrieved imprints, checked for consistency with what
the sensors felt, refined by ICP), and ``belief`` (ours: a pose belief over dense candidates,
weighed by a contact and no-contact likelihood, fused over touches and fingers).
"""

from tactojax.localize._belief import WITHIN_MM as WITHIN_MM
from tactojax.localize._belief import BeliefCalibration as BeliefCalibration
from tactojax.localize._belief import BeliefSettings as BeliefSettings
from tactojax.localize._belief import PoseBelief as PoseBelief
from tactojax.localize._belief import empty_belief as empty_belief
from tactojax.localize._belief import update_belief as update_belief
from tactojax.localize._calibrate import BeliefRecord as BeliefRecord
from tactojax.localize._calibrate import calibration_from_json as calibration_from_json
from tactojax.localize._calibrate import calibration_to_json as calibration_to_json
from tactojax.localize._calibrate import fit_calibration as fit_calibration
from tactojax.localize._calibrate import predict_within as predict_within
from tactojax.localize._calibrate import record_beliefs as record_beliefs
from tactojax.localize._candidates import CandidateGrid as CandidateGrid
from tactojax.localize._consistency import Consistency as Consistency
from tactojax.localize._consistency import consistency as consistency
from tactojax.localize._correspondences import Correspondences as Correspondences
from tactojax.localize._correspondences import find_correspondences as find_correspondences
from tactojax.localize._correspondences import nearest_correspondences as nearest_correspondences
from tactojax.localize._correspondences import surface_lookup as surface_lookup
from tactojax.localize._evaluate import HISTOGRAM_EDGES_MM as HISTOGRAM_EDGES_MM
from tactojax.localize._evaluate import MAP_FRACTIONS as MAP_FRACTIONS
from tactojax.localize._evaluate import LocalizationErrors as LocalizationErrors
from tactojax.localize._evaluate import cloud_moments as cloud_moments
from tactojax.localize._evaluate import cloud_rmse as cloud_rmse
from tactojax.localize._evaluate import evaluate_localization as evaluate_localization
from tactojax.localize._evaluate import map_size_study as map_size_study
from tactojax.localize._evaluate import moment_rmse as moment_rmse
from tactojax.localize._evaluate import oracle_imprints as oracle_imprints
from tactojax.localize._evaluate import pose_errors as pose_errors
from tactojax.localize._icp import ASSOCIATIONS as ASSOCIATIONS
from tactojax.localize._icp import ROBUST_LOSSES as ROBUST_LOSSES
from tactojax.localize._icp import IcpSettings as IcpSettings
from tactojax.localize._icp import fit_quality as fit_quality
from tactojax.localize._icp import icp as icp
from tactojax.localize._icp import robust_weights as robust_weights
from tactojax.localize._identify import IdentificationResult as IdentificationResult
from tactojax.localize._identify_episodes import identify_episodes as identify_episodes
from tactojax.localize._identify_episodes import shared_calibration as shared_calibration
from tactojax.localize._identify import MapLibrary as MapLibrary
from tactojax.localize._identify import evaluate_identification as evaluate_identification
from tactojax.localize._identify import identify as identify
from tactojax.localize._localizer import LiveEstimate as LiveEstimate
from tactojax.localize._localizer import Localizer as Localizer
from tactojax.localize._tracker import Tracker as Tracker
from tactojax.localize._tracker import TrackingSettings as TrackingSettings
from tactojax.localize._tracker import track_pose as track_pose
from tactojax.localize._tracker import tracking_starts as tracking_starts
from tactojax.localize._likelihood import LikelihoodSettings as LikelihoodSettings
from tactojax.localize._likelihood import TouchEvidence as TouchEvidence
from tactojax.localize._likelihood import log_likelihood as log_likelihood
from tactojax.localize._likelihood import point_log_likelihoods as point_log_likelihoods
from tactojax.localize._likelihood import touch_evidence as touch_evidence
from tactojax.localize._map import LocalizationMap as LocalizationMap
from tactojax.localize._map import Query as Query
from tactojax.localize._map import map_query as map_query
from tactojax.localize._methods import PAPER_METHODS as PAPER_METHODS
from tactojax.localize._methods import POINTS_PER_QUERY as POINTS_PER_QUERY
from tactojax.localize._methods import Method as Method
from tactojax.localize._methods import estimate_pose as estimate_pose
from tactojax.localize._methods import localize as localize
from tactojax.localize._methods import localize_query as localize_query
from tactojax.localize._methods import parse_method as parse_method
from tactojax.localize._methods import query_points as query_points
from tactojax.localize._new_grasps import EpisodeErrors as EpisodeErrors
from tactojax.localize._new_grasps import TestEpisodes as TestEpisodes
from tactojax.localize._new_grasps import calibration as calibration
from tactojax.localize._new_grasps import evaluate_new_grasps as evaluate_new_grasps
from tactojax.localize._pose import PoseEstimate as PoseEstimate
from tactojax.localize._register import register_multistart as register_multistart
from tactojax.localize._register import selection_cost as selection_cost
from tactojax.localize._retrieval import MAX_OPENING_DIFFERENCE_MM as MAX_OPENING_DIFFERENCE_MM
from tactojax.localize._retrieval import closest_imprints as closest_imprints
from tactojax.localize._retrieval import cosine_similarities as cosine_similarities
from tactojax.localize._retrieval import rank_imprints as rank_imprints
from tactojax.localize._search import SearchSettings as SearchSettings
from tactojax.localize._search import search_and_register as search_and_register
from tactojax.localize._search import verification_score as verification_score
from tactojax.localize._solvers import SOLVERS as SOLVERS
from tactojax.localize._solvers import pose_step as pose_step
from tactojax.localize._surface import MapSurface as MapSurface
from tactojax.localize._surface import SurfaceSettings as SurfaceSettings
from tactojax.localize._surface import build_map_surface as build_map_surface

__all__ = [
    "WITHIN_MM",
    "BeliefSettings",
    "CandidateGrid",
    "EpisodeErrors",
    "LikelihoodSettings",
    "PoseBelief",
    "MapSurface",
    "SurfaceSettings",
    "BeliefCalibration",
    "BeliefRecord",
    "calibration_from_json",
    "calibration_to_json",
    "fit_calibration",
    "predict_within",
    "record_beliefs",
    "TestEpisodes",
    "TouchEvidence",
    "build_map_surface",
    "calibration",
    "empty_belief",
    "evaluate_new_grasps",
    "log_likelihood",
    "point_log_likelihoods",
    "touch_evidence",
    "update_belief",
    "ASSOCIATIONS",
    "HISTOGRAM_EDGES_MM",
    "MAP_FRACTIONS",
    "MAX_OPENING_DIFFERENCE_MM",
    "PAPER_METHODS",
    "POINTS_PER_QUERY",
    "ROBUST_LOSSES",
    "SOLVERS",
    "Consistency",
    "Correspondences",
    "IcpSettings",
    "IdentificationResult",
    "LiveEstimate",
    "LocalizationErrors",
    "LocalizationMap",
    "Localizer",
    "Tracker",
    "TrackingSettings",
    "track_pose",
    "tracking_starts",
    "MapLibrary",
    "Method",
    "PoseEstimate",
    "Query",
    "SearchSettings",
    "closest_imprints",
    "cloud_moments",
    "cloud_rmse",
    "consistency",
    "cosine_similarities",
    "estimate_pose",
    "evaluate_identification",
    "evaluate_localization",
    "find_correspondences",
    "fit_quality",
    "icp",
    "identify",
    "identify_episodes",
    "shared_calibration",
    "localize",
    "localize_query",
    "map_query",
    "nearest_correspondences",
    "map_size_study",
    "moment_rmse",
    "oracle_imprints",
    "parse_method",
    "pose_errors",
    "pose_step",
    "query_points",
    "rank_imprints",
    "register_multistart",
    "robust_weights",
    "search_and_register",
    "verification_score",
    "selection_cost",
    "surface_lookup",
]
