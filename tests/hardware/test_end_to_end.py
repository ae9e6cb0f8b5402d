"""End to end on the simulated cell: record the mapping protocol through the camera, the WSG-50
emulator and the UDP pose feed; build a map from the recording; localize a new grasp."""

import jax
import jaxlie
import numpy as np
import pytest

from tactojax.features import encode_images
from tactojax.geometry import sensor_pose
from tactojax.hardware import Recorder, record_protocol, simulated_cell
from tactojax.io import load_encoder, open_dataset, read_grasps
from tactojax.localize import Localizer
from tactojax.mapping import build_tactile_map
from tactojax.objects import get_object
from tactojax.simulate import MappingProtocol, mapping_plan, simulate_to_dataset

PROTOCOL = MappingProtocol(grid_mm=30.0, yaws_deg=(0.0,))


@pytest.fixture(scope="module")
def recording(tmp_path_factory, small_spec):
    obj = get_object("gum_box")
    path = tmp_path_factory.mktemp("recording") / "gum_box"
    plan = mapping_plan(obj, PROTOCOL)
    with simulated_cell(small_spec, obj, transport="pty") as cell, Recorder(path, small_spec) as recorder:
        summary = record_protocol(cell.robot, cell.camera, cell.gripper.opening_mm, cell.poses, plan, recorder,
                                  object_id=obj.name, place_object=cell.scene.place_object, progress=False)
    return path, summary, obj


def test_recording_matches_the_simulator_run_directly(recording, small_spec, tmp_path):
    """The devices add nothing and lose nothing: openings and poses equal the simulator's own."""
    path, summary, obj = recording
    direct = tmp_path / "direct"
    simulate_to_dataset(direct, jax.random.key(0), small_spec, obj, PROTOCOL, progress=False)
    expected = open_dataset(direct).read(["opening_mm", "T_world_gripper", "T_world_object"])
    recorded = open_dataset(path).read()
    assert summary.recorded == len(expected["opening_mm"]) and summary.stale == 0
    np.testing.assert_allclose(recorded["opening_mm"], expected["opening_mm"], atol=1e-3)
    np.testing.assert_allclose(recorded["T_world_gripper"], expected["T_world_gripper"], atol=1e-3)
    np.testing.assert_allclose(recorded["T_world_object"], expected["T_world_object"], atol=1e-6)
    assert np.all(np.diff(recorded["timestamp_s"]) > 0)
    # Each frame was taken after its grasp closed: it shows contact (differs from the others' mean).
    assert recorded["image"].std(axis=0).max() > 0


@pytest.mark.slow  # compiles a live localizer for the recorded map (~15 s); tests/localize/test_localizer.py runs fuse
def test_a_new_grasp_is_localized_in_the_recorded_map(recording, small_spec, lookup_model, tiny_encoder_path):
    """A grasp off the mapping grid, through the cell's camera, gripper and pose feed: the
    belief puts the box where the scene holds it."""
    path, _, obj = recording
    grasps = read_grasps(path)
    tactile_map = build_tactile_map(lookup_model, grasps["images"], grasps["T_world_gripper"], grasps["openings"],
                                    grasps["object_id"], T_world_object=grasps["T_world_object"],
                                    points_per_imprint=256, progress=False)
    encoder = load_encoder(tiny_encoder_path)
    tactile_map = tactile_map.with_features(encode_images(encoder, tactile_map.images))
    localizer = Localizer([tactile_map], lookup_model, encoder)

    plan = mapping_plan(obj, PROTOCOL)
    index = int(np.argmax(np.asarray(grasps["openings"]) < 40.0))  # a grasp across the box's thin side
    T_commanded = jaxlie.SE3(plan.T_world_gripper.wxyz_xyz[int(grasps["index"][index])])
    shifted = T_commanded @ jaxlie.SE3.from_translation(np.array([2.0, 0.0, 1.5], np.float32))  # off the grid
    with simulated_cell(small_spec, obj, seed=7) as cell:
        cell.scene.place_object(jaxlie.SE3(plan.T_world_object.wxyz_xyz[int(grasps["index"][index])]))
        cell.robot.move_to(shifted)
        assert cell.robot.grasp() is not None
        frame = cell.camera.read()
        opening = cell.gripper.opening_mm()
        T_world_gripper = cell.poses.pose_at(frame.timestamp_s, max_skew_s=1.0).T_world_gripper  # the robot's feed
        estimate = localizer.fuse(frame.image, opening, T_world_gripper)  # the robot knows its grasp is done
        T_world_object = cell.scene.T_world_object
    T_object_sensor = T_world_object.inverse() @ sensor_pose(T_world_gripper, np.float32(opening))
    # The box is symmetric: the error is the smallest over its symmetry group.
    candidates = obj.symmetry.transforms() @ estimate.T_object_sensor
    errors = np.linalg.norm(np.asarray(candidates.translation()) - np.asarray(T_object_sensor.translation()),
                            axis=-1)
    copies = T_world_object @ obj.symmetry.transforms()
    offsets = np.linalg.norm(np.asarray((copies.inverse() @ estimate.T_world_object).translation()), axis=-1)
    print(f"new grasp: sensor position error {errors.min():.2f} mm, object position error {offsets.min():.2f} mm, "
          f"P(within 2 mm) {estimate.probability_within:.3f}")
    assert estimate.object_id == obj.name and estimate.contact and estimate.updated and estimate.grasps == 1
    assert estimate.object_probabilities == {obj.name: 1.0} and 0.0 <= estimate.probability_within <= 1.0
    assert errors.min() < 5.0 and offsets.min() < 5.0
