"""New-grasps datasets: episode numbering across appended objects, and reading a test set back."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax.geometry import opposite_sensor_pose
from tactojax.io import DatasetWriter, open_dataset, read_test_grasps
from tactojax.objects import get_object
from tactojax.simulate import GraspsProtocol, simulate_to_dataset

PROTOCOL = GraspsProtocol(episodes=2, grasps_per_episode=2, fingers=2)


@pytest.fixture(scope="module")
def test_set(tmp_path_factory, small_spec):
    path = tmp_path_factory.mktemp("data") / "test_grasps"
    for seed, name in enumerate(["cuboid", "cylinder"]):
        written = simulate_to_dataset(path, jax.random.key(seed), small_spec, get_object(name), PROTOCOL,
                                      progress=False)
        assert written == 2 * 2 * 2
    return path


def test_appended_objects_continue_the_episode_numbers(test_set):
    dataset = open_dataset(test_set)
    records = dataset.read(["object_id", "episode", "grasp", "finger"])
    np.testing.assert_array_equal(records["episode"], np.repeat([0, 1, 2, 3], 4))
    np.testing.assert_array_equal(records["object_id"], np.repeat(["cuboid", "cylinder"], 8))
    np.testing.assert_array_equal(records["grasp"], np.tile([0, 0, 1, 1], 4))
    np.testing.assert_array_equal(records["finger"], np.tile([0, 1], 8))
    assert dataset.metadata["protocol"] == {"name": "grasps", "episodes": 2, "grasps_per_episode": 2,
                                            "fingers": 2, "yaw_range_deg": 20.0,
                                            "turns_deg": [0.0, 90.0, 180.0, 270.0]}


def test_read_test_grasps_gives_complete_episodes(test_set, small_spec):
    data = read_test_grasps(test_set)
    assert data["image"].shape == (16, 60, 80, 3) and data["T_world_sensor"].shape == (16, 7)
    # (episode, grasp, finger) axes by reshaping; finger 1 sits at the opposite jaw.
    T_world_gripper = jaxlie.SE3(jnp.asarray(data["T_world_gripper"]))
    opposite = opposite_sensor_pose(T_world_gripper, jnp.asarray(data["opening_mm"]))
    by_finger = data["T_world_sensor"].reshape(4, 2, 2, 7)
    np.testing.assert_allclose(by_finger[:, :, 1], np.asarray(opposite.wxyz_xyz).reshape(4, 2, 2, 7)[:, :, 1],
                               atol=1e-5)
    cylinder = read_test_grasps(test_set, ["T_world_object", "opening_mm"], object_id="cylinder")
    assert set(cylinder) == {"T_world_object", "opening_mm", "object_id", "episode", "grasp", "finger"}
    np.testing.assert_array_equal(cylinder["episode"], np.repeat([2, 3], 4))
    np.testing.assert_array_equal(cylinder["opening_mm"], data["opening_mm"][8:])


def test_read_test_grasps_refuses_other_and_incomplete_datasets(test_set, mapping_dataset, tmp_path):
    with pytest.raises(ValueError, match="not new grasps"):
        read_test_grasps(mapping_dataset)
    with pytest.raises(ValueError, match="not in dataset"):
        read_test_grasps(test_set, object_id="teapot")
    # A run killed after its first imprints: the last episode lacks a grasp.
    dataset = open_dataset(test_set)
    truncated = tmp_path / "truncated"
    with DatasetWriter(truncated, metadata=dataset.metadata) as writer:
        for index in range(len(dataset) - 2):
            writer.append(dataset[index])
    with pytest.raises(ValueError, match="interrupted"):
        read_test_grasps(truncated)
    assert len(read_test_grasps(truncated, object_id="cuboid")["episode"]) == 8


def test_a_two_finger_test_set_is_not_read_as_mapping_grasps(test_set):
    from tactojax.io import read_grasps

    with pytest.raises(ValueError, match="second-finger imprints"):
        read_grasps(test_set, object_id="cuboid")
