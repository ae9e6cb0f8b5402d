"""Real hardware and its simulated stand-ins: tactile camera, WSG-50 gripper, robot pose, recorder.

Thin adapters that turn devices into the data the pipeline takes (rectified RGB frames,
openings in mm, ``T_world_gripper`` poses), each with a simulated or emulated twin so the same
code runs against the simulator:

- camera: :class:`OpenCVCamera` (USB device, video file or stream; four-corner rectification,
  background capture, dropped-frame detection), :class:`SimulatedCamera`;
- gripper: :class:`WSG50` (Weiss binary protocol over a serial port or ``socket://``),
  :class:`WSG50Emulator` (the same protocol over a pseudo-terminal or TCP, with faults);
- robot pose: :class:`PoseLog` (CSV/JSON), :class:`UdpPoseReceiver`; :func:`synchronise` pairs a
  frame with the opening and pose at its time;
- robot: the :class:`Robot` interface, :func:`execute_grasp` (approach, grasp, release,
  retreat), :class:`SimulatedRobot` on a :class:`SimulatedScene`, :func:`simulated_cell` for the
  whole simulated cell;
- active touch: :func:`active_episode` lets the live localizer choose every next grasp
  (:func:`~tactojax.localize.active.next_grasp`) until it is sure;
- recording: :class:`Recorder`, :func:`record_protocol` (the mapping protocol on any robot),
  :func:`record_grasps` (passive);
- live loop: :func:`live_estimates` runs a :class:`~tactojax.localize.Localizer` on frames;
- recorded ROS sessions: :func:`import_bag` turns a ROS 1/2 bag or MCAP file into a dataset,
  touches chosen and paired as a live recording does (``rosbags``, optional extra ``ros``).

Importing this package imports OpenCV and pyserial; the numerical core never does.
"""

from tactojax.hardware._active import ActiveStep as ActiveStep
from tactojax.hardware._active import active_episode as active_episode
from tactojax.hardware._bag_import import BagImportSummary as BagImportSummary
from tactojax.hardware._bag_import import GraspDetection as GraspDetection
from tactojax.hardware._bag_import import detect_grasps as detect_grasps
from tactojax.hardware._bag_import import import_bag as import_bag
from tactojax.hardware._camera import Camera as Camera
from tactojax.hardware._camera import CameraError as CameraError
from tactojax.hardware._camera import LOSSLESS_FOURCC as LOSSLESS_FOURCC
from tactojax.hardware._camera import EndOfStream as EndOfStream
from tactojax.hardware._camera import Frame as Frame
from tactojax.hardware._camera import OpenCVCamera as OpenCVCamera
from tactojax.hardware._camera import rectify_image as rectify_image
from tactojax.hardware._camera import validate_corners as validate_corners
from tactojax.hardware._camera import write_video as write_video
from tactojax.hardware._live import LatestFrame as LatestFrame
from tactojax.hardware._live import ReadAhead as ReadAhead
from tactojax.hardware._live import LiveStatistics as LiveStatistics
from tactojax.hardware._live import PoseLookup as PoseLookup
from tactojax.hardware._live import live_estimates as live_estimates
from tactojax.hardware._pose_source import PoseLog as PoseLog
from tactojax.hardware._pose_source import PoseSample as PoseSample
from tactojax.hardware._pose_source import PoseSource as PoseSource
from tactojax.hardware._pose_source import StaleDataError as StaleDataError
from tactojax.hardware._pose_source import UdpPoseReceiver as UdpPoseReceiver
from tactojax.hardware._pose_source import read_pose_log as read_pose_log
from tactojax.hardware._pose_source import send_pose as send_pose
from tactojax.hardware._pose_source import write_pose_log as write_pose_log
from tactojax.hardware._pose_source import decode_pose_packet as decode_pose_packet
from tactojax.hardware._pose_source import encode_pose_packet as encode_pose_packet
from tactojax.hardware._pose_source import pose_at_time as pose_at_time
from tactojax.hardware._recorder import Recorder as Recorder
from tactojax.hardware._recorder import RecordingSummary as RecordingSummary
from tactojax.hardware._recorder import record_grasps as record_grasps
from tactojax.hardware._recorder import record_protocol as record_protocol
from tactojax.hardware._robot import APPROACH_MM as APPROACH_MM
from tactojax.hardware._robot import ExecutedGrasp as ExecutedGrasp
from tactojax.hardware._robot import Robot as Robot
from tactojax.hardware._robot import approach_pose as approach_pose
from tactojax.hardware._robot import execute_grasp as execute_grasp
from tactojax.hardware._rosbag import BagError as BagError
from tactojax.hardware._rosbag import GripperJoints as GripperJoints
from tactojax.hardware._rosbag import TransformChain as TransformChain
from tactojax.hardware._rosbag import bag_topics as bag_topics
from tactojax.hardware._rosbag import open_bag as open_bag
from tactojax.hardware._rosbag import read_streams as read_streams
from tactojax.hardware._simulated import PosePublisher as PosePublisher
from tactojax.hardware._simulated import SimulatedCamera as SimulatedCamera
from tactojax.hardware._simulated import SimulatedCell as SimulatedCell
from tactojax.hardware._simulated import SimulatedRobot as SimulatedRobot
from tactojax.hardware._simulated import SimulatedScene as SimulatedScene
from tactojax.hardware._simulated import simulated_cell as simulated_cell
from tactojax.hardware._sync import SynchronisedTouch as SynchronisedTouch
from tactojax.hardware._sync import OpeningSamples as OpeningSamples
from tactojax.hardware._sync import opening_at as opening_at
from tactojax.hardware._sync import synchronise as synchronise
from tactojax.hardware._wsg50 import WSG50 as WSG50
from tactojax.hardware._wsg50_emulator import EmulatorFault as EmulatorFault
from tactojax.hardware._wsg50_emulator import WSG50Emulator as WSG50Emulator
from tactojax.hardware._wsg50_protocol import GraspingState as GraspingState
from tactojax.hardware._wsg50_protocol import GripperChecksumError as GripperChecksumError
from tactojax.hardware._wsg50_protocol import GripperDisconnectedError as GripperDisconnectedError
from tactojax.hardware._wsg50_protocol import GripperError as GripperError
from tactojax.hardware._wsg50_protocol import GripperStatus as GripperStatus
from tactojax.hardware._wsg50_protocol import GripperProtocolError as GripperProtocolError
from tactojax.hardware._wsg50_protocol import GripperStatusError as GripperStatusError
from tactojax.hardware._wsg50_protocol import GripperTimeoutError as GripperTimeoutError
