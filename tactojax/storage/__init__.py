"""Storage: the file formats under every stage. It imports no stage.

Atomic writes, the chunked dataset format and its repair, meshes (loading, checks, repair),
taxim calibration packs, PyTorch weights (read without torch or pickle), the checkpoint
container, and new-grasps test sets read back as arrays. ``tactojax.io`` re-exports the public
names, so a user reads and writes everything from one place; the stages import them from here.

Layers, bottom to top; each imports only those below it, also inside functions (checked by
``lint-imports``, the contract in ``pyproject.toml``):

1. ``storage``: numpy, trimesh, flax's msgpack; no stage.
2. ``geometry`` -> ``sensor`` -> ``objects`` -> ``simulate`` -> ``shape`` -> ``mapping`` ->
   ``features`` -> ``localize``: the pipeline stages. A stage that needs a file's content reads
   it through storage or takes it as an argument; it never imports ``tactojax.io``.
3. ``io``: stage-specific load and save (shape models, encoders, maps, imprints, presses).
4. ``hardware`` and ``viz`` (independent of each other).
5. ``cli``: the command line, calling all of the above.
"""

from tactojax.storage._atomic import atomic_open as atomic_open
from tactojax.storage._atomic import atomic_write_bytes as atomic_write_bytes
from tactojax.storage._checkpoint import CorruptCheckpointError as CorruptCheckpointError
from tactojax.storage._checkpoint import read_checkpoint_payload as read_checkpoint_payload
from tactojax.storage._dataset import ChunkProblem as ChunkProblem
from tactojax.storage._dataset import CorruptChunkError as CorruptChunkError
from tactojax.storage._dataset import CorruptDatasetError as CorruptDatasetError
from tactojax.storage._dataset import Dataset as Dataset
from tactojax.storage._dataset import dataset_summary as dataset_summary
from tactojax.storage._dataset import DatasetLockedError as DatasetLockedError
from tactojax.storage._dataset import DatasetWriter as DatasetWriter
from tactojax.storage._dataset import infer_schema as infer_schema
from tactojax.storage._dataset import open_dataset as open_dataset
from tactojax.storage._dataset_repair import DatasetRepair as DatasetRepair
from tactojax.storage._dataset_repair import repair_dataset as repair_dataset
from tactojax.storage._mesh import check_mesh as check_mesh
from tactojax.storage._mesh import InvalidMeshError as InvalidMeshError
from tactojax.storage._mesh import load_mesh as load_mesh
from tactojax.storage._mesh import MESH_UNITS_TO_MM as MESH_UNITS_TO_MM
from tactojax.storage._mesh import ycb_mesh_path as ycb_mesh_path
from tactojax.storage._mesh_repair import MeshRepair as MeshRepair
from tactojax.storage._mesh_repair import MeshRepairedWarning as MeshRepairedWarning
from tactojax.storage._mesh_repair import repair_mesh as repair_mesh
from tactojax.storage._taxim import load_taxim_calibration as load_taxim_calibration
from tactojax.storage._taxim import MissingDataPackageError as MissingDataPackageError
from tactojax.storage._taxim import taxim_calibration_dir as taxim_calibration_dir
from tactojax.storage._taxim import TAXIM_SENSORS as TAXIM_SENSORS
from tactojax.storage._taxim import TaximCalibration as TaximCalibration
from tactojax.storage._test_grasps import read_test_grasps as read_test_grasps
from tactojax.storage._torch_weights import CorruptTorchCheckpointError as CorruptTorchCheckpointError
from tactojax.storage._torch_weights import load_torch_state_dict as load_torch_state_dict
from tactojax.storage._torch_weights import UnsafeCheckpointError as UnsafeCheckpointError

__all__ = [
    "atomic_open",
    "atomic_write_bytes",
    "check_mesh",
    "ChunkProblem",
    "CorruptCheckpointError",
    "CorruptChunkError",
    "CorruptDatasetError",
    "CorruptTorchCheckpointError",
    "Dataset",
    "dataset_summary",
    "DatasetLockedError",
    "DatasetRepair",
    "DatasetWriter",
    "infer_schema",
    "InvalidMeshError",
    "load_mesh",
    "load_taxim_calibration",
    "load_torch_state_dict",
    "MESH_UNITS_TO_MM",
    "MeshRepair",
    "MeshRepairedWarning",
    "MissingDataPackageError",
    "open_dataset",
    "read_checkpoint_payload",
    "read_test_grasps",
    "repair_dataset",
    "repair_mesh",
    "taxim_calibration_dir",
    "TAXIM_SENSORS",
    "TaximCalibration",
    "UnsafeCheckpointError",
    "ycb_mesh_path",
]
