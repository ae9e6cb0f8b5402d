"""All disk I/O: taxim calibrations, meshes, datasets."""

from tactojax.io._dataset import CorruptDatasetError as CorruptDatasetError
from tactojax.io._dataset import Dataset as Dataset
from tactojax.io._dataset import DatasetLockedError as DatasetLockedError
from tactojax.io._dataset import DatasetWriter as DatasetWriter
from tactojax.io._dataset import dataset_summary as dataset_summary
from tactojax.io._dataset import infer_schema as infer_schema
from tactojax.io._dataset import open_dataset as open_dataset
from tactojax.io._dataset import ChunkProblem as ChunkProblem
from tactojax.io._dataset import CorruptChunkError as CorruptChunkError
from tactojax.io._dataset_repair import DatasetRepair as DatasetRepair
from tactojax.io._dataset_repair import repair_dataset as repair_dataset
from tactojax.io._imprints import sensor_metadata as sensor_metadata
from tactojax.io._encoder import bundled_encoders as bundled_encoders
from tactojax.io._encoder import encoder_metadata as encoder_metadata
from tactojax.io._encoder import load_encoder as load_encoder
from tactojax.io._encoder import load_encoder_train_state as load_encoder_train_state
from tactojax.io._encoder import DEFAULT_ENCODER as DEFAULT_ENCODER
from tactojax.io._encoder import resolve_encoder as resolve_encoder
from tactojax.io._encoder import save_encoder as save_encoder
from tactojax.io._encoder import save_encoder_train_state as save_encoder_train_state
from tactojax.io._imprints import dataset_metadata as dataset_metadata
from tactojax.io._imprints import load_imprints as load_imprints
from tactojax.io._imprints import simulate_to_dataset as simulate_to_dataset
from tactojax.io._map import CorruptMapError as CorruptMapError
from tactojax.io._map import export_ply as export_ply
from tactojax.io._map import load_localization_map as load_localization_map
from tactojax.io._map import load_tactile_map as load_tactile_map
from tactojax.io._map import read_grasps as read_grasps
from tactojax.io._map import save_tactile_map as save_tactile_map
from tactojax.io._map import tactile_map_metadata as tactile_map_metadata
from tactojax.io._mesh import InvalidMeshError as InvalidMeshError
from tactojax.io._mesh import MESH_UNITS_TO_MM as MESH_UNITS_TO_MM
from tactojax.io._mesh import check_mesh as check_mesh
from tactojax.io._mesh import load_mesh as load_mesh
from tactojax.io._mesh import ycb_mesh_path as ycb_mesh_path
from tactojax.io._mesh_repair import MeshRepair as MeshRepair
from tactojax.io._mesh_repair import MeshRepairedWarning as MeshRepairedWarning
from tactojax.io._mesh_repair import repair_mesh as repair_mesh
from tactojax.io._presses import load_ball_presses as load_ball_presses
from tactojax.io._shape import CorruptCheckpointError as CorruptCheckpointError
from tactojax.io._shape import bundled_shape_models as bundled_shape_models
from tactojax.io._shape import load_shape_data as load_shape_data
from tactojax.io._shape import load_shape_model as load_shape_model
from tactojax.io._shape import load_train_state as load_train_state
from tactojax.io._shape import resolve_shape_model as resolve_shape_model
from tactojax.io._shape import save_shape_model as save_shape_model
from tactojax.io._shape import save_train_state as save_train_state
from tactojax.io._shape import shape_model_metadata as shape_model_metadata
from tactojax.io._touches import load_touches as load_touches
from tactojax.io._test_grasps import load_test_episodes as load_test_episodes
from tactojax.io._test_grasps import read_test_grasps as read_test_grasps
from tactojax.io._taxim import TAXIM_SENSORS as TAXIM_SENSORS
from tactojax.io._taxim import MissingDataPackageError as MissingDataPackageError
from tactojax.io._taxim import TaximCalibration as TaximCalibration
from tactojax.io._taxim import load_taxim_calibration as load_taxim_calibration
from tactojax.io._taxim import taxim_calibration_dir as taxim_calibration_dir
from tactojax.io._torch_weights import CorruptTorchCheckpointError as CorruptTorchCheckpointError
from tactojax.io._torch_weights import UnsafeCheckpointError as UnsafeCheckpointError
from tactojax.io._torch_weights import load_torch_state_dict as load_torch_state_dict

__all__ = [
    "CorruptDatasetError",
    "Dataset",
    "DatasetLockedError",
    "DatasetWriter",
    "bundled_encoders",
    "encoder_metadata",
    "load_encoder",
    "load_encoder_train_state",
    "load_touches",
    "resolve_encoder",
    "DEFAULT_ENCODER",
    "save_encoder",
    "save_encoder_train_state",
    "sensor_metadata",
    "dataset_metadata",
    "dataset_summary",
    "infer_schema",
    "load_imprints",
    "open_dataset",
    "ChunkProblem",
    "CorruptChunkError",
    "DatasetRepair",
    "repair_dataset",
    "simulate_to_dataset",
    "CorruptMapError",
    "export_ply",
    "load_localization_map",
    "load_tactile_map",
    "read_grasps",
    "load_test_episodes",
    "read_test_grasps",
    "save_tactile_map",
    "tactile_map_metadata",
    "InvalidMeshError",
    "MESH_UNITS_TO_MM",
    "check_mesh",
    "load_mesh",
    "ycb_mesh_path",
    "MeshRepair",
    "MeshRepairedWarning",
    "repair_mesh",
    "load_ball_presses",
    "CorruptCheckpointError",
    "bundled_shape_models",
    "load_shape_data",
    "load_shape_model",
    "load_train_state",
    "resolve_shape_model",
    "save_shape_model",
    "save_train_state",
    "shape_model_metadata",
    "TAXIM_SENSORS",
    "MissingDataPackageError",
    "TaximCalibration",
    "load_taxim_calibration",
    "taxim_calibration_dir",
    "CorruptTorchCheckpointError",
    "UnsafeCheckpointError",
    "load_torch_state_dict",
]
