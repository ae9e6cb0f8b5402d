"""Local shape (paper section IV): tactile image -> contact heightmap and mask. Pure JAX."""

from tactojax.shape._calibrate import BallPresses as BallPresses
from tactojax.shape._calibrate import BallRadiusNotIdentifiableError as BallRadiusNotIdentifiableError
from tactojax.shape._calibrate import ball_press_data as ball_press_data
from tactojax.shape._calibrate import calibrate_from_presses as calibrate_from_presses
from tactojax.shape._calibrate import estimate_ball_radius as estimate_ball_radius
from tactojax.shape._calibrate import evaluate_ball_fit as evaluate_ball_fit
from tactojax.shape._calibrate import fit_sphere_cap as fit_sphere_cap
from tactojax.shape._data import ShapeData as ShapeData
from tactojax.shape._data import balanced_subset as balanced_subset
from tactojax.shape._data import estimate_background as estimate_background
from tactojax.shape._data import split_held_out as split_held_out
from tactojax.shape._lookup import fit_lookup_model as fit_lookup_model
from tactojax.shape._lookup import fit_lookup_table as fit_lookup_table
from tactojax.shape._lookup import lookup_slope as lookup_slope
from tactojax.shape._metrics import batch_heightmap_errors as batch_heightmap_errors
from tactojax.shape._metrics import evaluate_shape_model as evaluate_shape_model
from tactojax.shape._metrics import heightmap_errors as heightmap_errors
from tactojax.shape._metrics import summarize_errors as summarize_errors
from tactojax.shape._models import PRESETS as PRESETS
from tactojax.shape._models import build_network as build_network
from tactojax.shape._models import flops_per_pixel as flops_per_pixel
from tactojax.shape._models import MASK_SHARPNESS_MM as MASK_SHARPNESS_MM
from tactojax.shape._models import patch_planes as patch_planes
from tactojax.shape._models import pixel_patches as pixel_patches
from tactojax.shape._poisson import integrate_gradient as integrate_gradient
from tactojax.shape._poisson import zero_background as zero_background
from tactojax.shape._predict import LOOKUP as LOOKUP
from tactojax.shape._robustness import robustness_study as robustness_study
from tactojax.shape._predict import ShapeModel as ShapeModel
from tactojax.shape._predict import check_image as check_image
from tactojax.shape._predict import coordinate_bias as coordinate_bias
from tactojax.shape._predict import init_shape_model as init_shape_model
from tactojax.shape._predict import network_input as network_input
from tactojax.shape._predict import predict as predict
from tactojax.shape._predict import predict_batch as predict_batch
from tactojax.shape._quantile import order_statistics as order_statistics
from tactojax.shape._train import TrainConfig as TrainConfig
from tactojax.shape._train import TrainState as TrainState
from tactojax.shape._train import init_train_state as init_train_state
from tactojax.shape._train import make_optimizer as make_optimizer
from tactojax.shape._train import train_shape_model as train_shape_model

__all__ = [
    "BallPresses",
    "BallRadiusNotIdentifiableError",
    "ball_press_data",
    "calibrate_from_presses",
    "estimate_ball_radius",
    "evaluate_ball_fit",
    "fit_sphere_cap",
    "LOOKUP",
    "PRESETS",
    "ShapeData",
    "ShapeModel",
    "TrainConfig",
    "TrainState",
    "balanced_subset",
    "batch_heightmap_errors",
    "build_network",
    "check_image",
    "coordinate_bias",
    "estimate_background",
    "evaluate_shape_model",
    "fit_lookup_model",
    "fit_lookup_table",
    "flops_per_pixel",
    "heightmap_errors",
    "init_shape_model",
    "init_train_state",
    "integrate_gradient",
    "lookup_slope",
    "make_optimizer",
    "order_statistics",
    "predict",
    "predict_batch",
    "robustness_study",
    "split_held_out",
    "summarize_errors",
    "train_shape_model",
    "zero_background",
    "MASK_SHARPNESS_MM",
    "patch_planes",
    "pixel_patches",
    "network_input",
]
