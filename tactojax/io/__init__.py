"""Disk I/O for users: everything tactojax reads and writes, from one place.

Stage-specific load and save live here (shape models, encoders, tactile and localization maps,
imprint batches, ball presses, touches); the file formats under them (datasets, meshes, taxim
packs, torch weights, checkpoints, test sets as arrays) live in :mod:`tactojax.storage` and are
re-exported. This layer sits above the stages: no stage imports it (see ``tactojax.storage``).
"""

from tactojax._moved import moved_names
from tactojax.io._encoder import bundled_encoders as bundled_encoders
from tactojax.io._encoder import DEFAULT_ENCODER as DEFAULT_ENCODER
from tactojax.io._encoder import encoder_label as encoder_label
from tactojax.io._encoder import encoder_metadata as encoder_metadata
from tactojax.io._encoder import load_encoder as load_encoder
from tactojax.io._encoder import load_encoder_train_state as load_encoder_train_state
from tactojax.io._encoder import resolve_encoder as resolve_encoder
from tactojax.io._encoder import save_encoder as save_encoder
from tactojax.io._encoder import save_encoder_train_state as save_encoder_train_state
from tactojax.io._imprints import load_imprints as load_imprints
from tactojax.io._catalog import catalog_maps as catalog_maps
from tactojax.io._catalog import catalog_slug as catalog_slug
from tactojax.io._catalog import expand_catalogs as expand_catalogs
from tactojax.io._catalog import is_catalog as is_catalog
from tactojax.io._catalog import read_catalog as read_catalog
from tactojax.io._catalog import write_catalog as write_catalog
from tactojax.io._map import MAP_VERSION as MAP_VERSION
from tactojax.io._map import CorruptMapError as CorruptMapError
from tactojax.io._map import compact_tactile_map as compact_tactile_map
from tactojax.io._map import dataset_symmetry as dataset_symmetry
from tactojax.io._map import export_ply as export_ply
from tactojax.io._map import load_localization_map as load_localization_map
from tactojax.io._map import load_tactile_map as load_tactile_map
from tactojax.io._map import load_tactile_map_with_features as load_tactile_map_with_features
from tactojax.io._map import maps_encoder_name as maps_encoder_name
from tactojax.io._map import read_grasps as read_grasps
from tactojax.io._map import save_tactile_map as save_tactile_map
from tactojax.io._map import stored_features_encoder as stored_features_encoder
from tactojax.io._map import stored_surface as stored_surface
from tactojax.io._map import tactile_map_bytes as tactile_map_bytes
from tactojax.io._map import tactile_map_metadata as tactile_map_metadata
from tactojax.io._map import update_tactile_map_metadata as update_tactile_map_metadata
from tactojax.io._presses import load_ball_presses as load_ball_presses
from tactojax.io._shape import bundled_shape_models as bundled_shape_models
from tactojax.io._shape import load_shape_data as load_shape_data
from tactojax.io._shape import load_shape_model as load_shape_model
from tactojax.io._shape import load_train_state as load_train_state
from tactojax.io._shape import resolve_shape_model as resolve_shape_model
from tactojax.io._shape import save_shape_model as save_shape_model
from tactojax.io._shape import save_train_state as save_train_state
from tactojax.io._shape import shape_model_metadata as shape_model_metadata
from tactojax.io._touches import load_touches as load_touches
from tactojax.storage import CorruptCheckpointError as CorruptCheckpointError
from tactojax.storage import ChunkProblem as ChunkProblem
from tactojax.storage import CorruptChunkError as CorruptChunkError
from tactojax.storage import CorruptDatasetError as CorruptDatasetError
from tactojax.storage import Dataset as Dataset
from tactojax.storage import dataset_summary as dataset_summary
from tactojax.storage import DatasetLockedError as DatasetLockedError
from tactojax.storage import DatasetWriter as DatasetWriter
from tactojax.storage import infer_schema as infer_schema
from tactojax.storage import open_dataset as open_dataset
from tactojax.storage import DatasetRepair as DatasetRepair
from tactojax.storage import repair_dataset as repair_dataset
from tactojax.storage import check_mesh as check_mesh
from tactojax.storage import InvalidMeshError as InvalidMeshError
from tactojax.storage import load_mesh as load_mesh
from tactojax.storage import MESH_UNITS_TO_MM as MESH_UNITS_TO_MM
from tactojax.storage import ycb_mesh_path as ycb_mesh_path
from tactojax.storage import MeshRepair as MeshRepair
from tactojax.storage import MeshRepairedWarning as MeshRepairedWarning
from tactojax.storage import repair_mesh as repair_mesh
from tactojax.storage import load_taxim_calibration as load_taxim_calibration
from tactojax.storage import MissingDataPackageError as MissingDataPackageError
from tactojax.storage import taxim_calibration_dir as taxim_calibration_dir
from tactojax.storage import TAXIM_SENSORS as TAXIM_SENSORS
from tactojax.storage import TaximCalibration as TaximCalibration
from tactojax.storage import read_test_grasps as read_test_grasps
from tactojax.storage import CorruptTorchCheckpointError as CorruptTorchCheckpointError
from tactojax.storage import load_torch_state_dict as load_torch_state_dict
from tactojax.storage import UnsafeCheckpointError as UnsafeCheckpointError

_MOVED = {
    "dataset_metadata": "tactojax.simulate",
    "load_test_episodes": "tactojax.localize.evaluation",
    "sensor_metadata": "tactojax.simulate",
    "simulate_to_dataset": "tactojax.simulate",
}
"""Names that moved to their stage: ``tactojax.io.NAME`` still works, with a DeprecationWarning."""


__getattr__ = moved_names(__name__, _MOVED)

__all__ = [
    "catalog_maps",
    "catalog_slug",
    "expand_catalogs",
    "is_catalog",
    "read_catalog",
    "write_catalog",
    "bundled_encoders",
    "bundled_shape_models",
    "check_mesh",
    "ChunkProblem",
    "compact_tactile_map",
    "CorruptCheckpointError",
    "CorruptChunkError",
    "CorruptDatasetError",
    "CorruptMapError",
    "CorruptTorchCheckpointError",
    "Dataset",
    "dataset_summary",
    "dataset_symmetry",
    "DatasetLockedError",
    "DatasetRepair",
    "DatasetWriter",
    "DEFAULT_ENCODER",
    "encoder_metadata",
    "export_ply",
    "infer_schema",
    "InvalidMeshError",
    "load_ball_presses",
    "load_encoder",
    "load_encoder_train_state",
    "load_imprints",
    "load_localization_map",
    "load_mesh",
    "load_shape_data",
    "load_shape_model",
    "load_tactile_map",
    "load_tactile_map_with_features",
    "load_taxim_calibration",
    "load_torch_state_dict",
    "load_touches",
    "load_train_state",
    "MAP_VERSION",
    "maps_encoder_name",
    "MESH_UNITS_TO_MM",
    "MeshRepair",
    "MeshRepairedWarning",
    "MissingDataPackageError",
    "open_dataset",
    "read_grasps",
    "read_test_grasps",
    "repair_dataset",
    "repair_mesh",
    "resolve_encoder",
    "resolve_shape_model",
    "save_encoder",
    "save_encoder_train_state",
    "save_shape_model",
    "save_tactile_map",
    "save_train_state",
    "shape_model_metadata",
    "stored_features_encoder",
    "stored_surface",
    "tactile_map_bytes",
    "tactile_map_metadata",
    "taxim_calibration_dir",
    "TAXIM_SENSORS",
    "TaximCalibration",
    "UnsafeCheckpointError",
    "update_tactile_map_metadata",
    "ycb_mesh_path",
]
