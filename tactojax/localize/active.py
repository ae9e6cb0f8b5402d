"""Active touch: which grasp next, and when to stop.

:func:`propose_grasps` draws candidate grasps around the belief's leading hypotheses,
:func:`predict_grasp` predicts what each finger would feel from the map's surface alone,
:func:`next_grasp` ranks the candidates by the expected gain in P(within 2 mm) (or in entropy)
among those likeliest to close (where the belief's search may have missed the truth, those that
close across a contact already felt, :func:`closes_across_felt`),
:func:`observe_failed_grasp` learns from a grasp that missed or collided, and :func:`should_stop`
says when the calibrated belief is sure enough.
"""

from tactojax.localize._active import ActiveSettings as ActiveSettings
from tactojax.localize._active import GraspRanking as GraspRanking
from tactojax.localize._active import closes_across_felt as closes_across_felt
from tactojax.localize._active import next_grasp as next_grasp
from tactojax.localize._active import observe_failed_grasp as observe_failed_grasp
from tactojax.localize._active import propose_grasps as propose_grasps
from tactojax.localize._active import should_stop as should_stop
from tactojax.localize._predict_touch import MarchingGrid as MarchingGrid
from tactojax.localize._predict_touch import PredictedGrasp as PredictedGrasp
from tactojax.localize._predict_touch import PredictionSettings as PredictionSettings
from tactojax.localize._predict_touch import StackedMarchingGrids as StackedMarchingGrids
from tactojax.localize._predict_touch import map_marching_grid as map_marching_grid
from tactojax.localize._predict_touch import predict_grasp as predict_grasp

__all__ = [
    "ActiveSettings",
    "GraspRanking",
    "MarchingGrid",
    "PredictedGrasp",
    "PredictionSettings",
    "StackedMarchingGrids",
    "closes_across_felt",
    "map_marching_grid",
    "next_grasp",
    "observe_failed_grasp",
    "predict_grasp",
    "propose_grasps",
    "should_stop",
]
