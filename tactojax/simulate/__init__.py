"""Simulation: grasps and touches of objects, the paper's exploration protocols, and their datasets."""

from tactojax.simulate._dataset import dataset_metadata as dataset_metadata
from tactojax.simulate._dataset import sensor_metadata as sensor_metadata
from tactojax.simulate._dataset import simulate_to_dataset as simulate_to_dataset
from tactojax.simulate._dataset import symmetry_key as symmetry_key
from tactojax.simulate._grasp import GraspConfig as GraspConfig
from tactojax.simulate._grasp import GraspResult as GraspResult
from tactojax.simulate._grasp import simulate_grasps as simulate_grasps
from tactojax.simulate._grasp import simulate_two_sensor_grasps as simulate_two_sensor_grasps
from tactojax.simulate._protocols import CalibrationProtocol as CalibrationProtocol
from tactojax.simulate._protocols import GraspCandidates as GraspCandidates
from tactojax.simulate._protocols import GraspPlan as GraspPlan
from tactojax.simulate._protocols import GraspsProtocol as GraspsProtocol
from tactojax.simulate._protocols import MappingProtocol as MappingProtocol
from tactojax.simulate._protocols import TouchPlan as TouchPlan
from tactojax.simulate._protocols import calibration_plan as calibration_plan
from tactojax.simulate._protocols import grasps_plan as grasps_plan
from tactojax.simulate._protocols import mapping_grid_for as mapping_grid_for
from tactojax.simulate._protocols import mapping_plan as mapping_plan
from tactojax.simulate._run import plan_protocol as plan_protocol
from tactojax.simulate._run import protocol_fields as protocol_fields
from tactojax.simulate._run import simulate_protocol as simulate_protocol
from tactojax.simulate._slip import SlipProtocol as SlipProtocol
from tactojax.simulate._slip import SlipWalk as SlipWalk
from tactojax.simulate._slip import slip_offsets as slip_offsets
from tactojax.simulate._slip import slipped_grippers as slipped_grippers
from tactojax.simulate._touch import cast_rays as cast_rays
from tactojax.simulate._touch import pad_rays as pad_rays
from tactojax.simulate._touch import touch as touch

__all__ = [
    "CalibrationProtocol", "GraspCandidates", "GraspConfig", "GraspPlan", "GraspResult", "GraspsProtocol",
    "MappingProtocol", "SlipProtocol", "SlipWalk", "TouchPlan", "calibration_plan", "cast_rays", "dataset_metadata",
    "grasps_plan", "mapping_grid_for", "mapping_plan", "pad_rays", "plan_protocol", "protocol_fields",
    "sensor_metadata", "simulate_grasps", "simulate_protocol", "simulate_to_dataset", "simulate_two_sensor_grasps", "symmetry_key",
    "slip_offsets", "slipped_grippers", "touch",
]
