"""Global tactile maps (paper section V): imprints placed by the kinematics, shape recovery."""

from tactojax.mapping._build import DEFAULT_POINTS_PER_IMPRINT as DEFAULT_POINTS_PER_IMPRINT
from tactojax.mapping._build import build_tactile_map as build_tactile_map
from tactojax.mapping._build import observed_contact as observed_contact
from tactojax.mapping._build import shows_contact as shows_contact
from tactojax.mapping._build import may_show_contact as may_show_contact
from tactojax.mapping._build import sample_contact_pixels as sample_contact_pixels
from tactojax.mapping._build import sample_contact_points as sample_contact_points
from tactojax.mapping._cloud import point_surface_distances as point_surface_distances
from tactojax.mapping._cloud import stitched_point_cloud as stitched_point_cloud
from tactojax.mapping._cloud import surface_distance as surface_distance
from tactojax.mapping._cloud import voxel_downsample as voxel_downsample
from tactojax.mapping._map import TactileMap as TactileMap
from tactojax.mapping._packing import pack_heightmaps as pack_heightmaps
from tactojax.mapping._packing import pixel_index_dtype as pixel_index_dtype
from tactojax.mapping._packing import pixel_points as pixel_points
from tactojax.mapping._packing import points_to_pixels as points_to_pixels
from tactojax.mapping._packing import unpack_heightmaps as unpack_heightmaps
from tactojax.mapping._noise import NOISE_LEVELS as NOISE_LEVELS
from tactojax.mapping._noise import KinematicNoise as KinematicNoise
from tactojax.mapping._noise import perturb_kinematics as perturb_kinematics
from tactojax.mapping._recover import fit_shape_to_clouds as fit_shape_to_clouds
from tactojax.mapping._recover import fit_tactile_map as fit_tactile_map
from tactojax.mapping._recover import shape_fit_clouds as shape_fit_clouds
from tactojax.mapping._reliable import depth_observed as depth_observed
from tactojax.mapping._reliable import membrane_skirt as membrane_skirt
from tactojax.mapping._shape_fit import SHAPE_KINDS as SHAPE_KINDS
from tactojax.mapping._shape_fit import ShapeFit as ShapeFit
from tactojax.mapping._shape_fit import fit_shape as fit_shape
from tactojax.mapping._shape_fit import shape_fit_errors as shape_fit_errors
from tactojax.mapping._shape_fit import true_shape_parameters as true_shape_parameters

__all__ = [
    "DEFAULT_POINTS_PER_IMPRINT",
    "NOISE_LEVELS",
    "SHAPE_KINDS",
    "KinematicNoise",
    "ShapeFit",
    "TactileMap",
    "build_tactile_map",
    "depth_observed",
    "fit_shape",
    "fit_shape_to_clouds",
    "fit_tactile_map",
    "membrane_skirt",
    "observed_contact",
    "pack_heightmaps",
    "pixel_index_dtype",
    "pixel_points",
    "points_to_pixels",
    "sample_contact_pixels",
    "shows_contact",
    "may_show_contact",
    "perturb_kinematics",
    "point_surface_distances",
    "sample_contact_points",
    "shape_fit_clouds",
    "shape_fit_errors",
    "stitched_point_cloud",
    "surface_distance",
    "true_shape_parameters",
    "unpack_heightmaps",
    "voxel_downsample",
]
