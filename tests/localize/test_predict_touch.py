"""The touch a grasp would give, predicted from the map's surface, against the simulator's."""

import jax
import jaxlie
import numpy as np
import pytest

from tactojax.localize.active import PredictionSettings, map_marching_grid, predict_grasp
from tactojax.objects import get_object
from tactojax.simulate import GraspsProtocol, simulate_two_sensor_grasps
from tactojax.simulate._protocols import grasp_candidates

from active_fixtures import truth_map


@pytest.fixture(scope="module")
def gum_box_truth_view(small_spec):
    return truth_map(small_spec, get_object("gum_box"), grid_mm=15.0)


def test_predicted_touch_matches_the_simulator_at_the_true_pose(small_spec, gum_box_truth_view):
    obj, view = get_object("gum_box"), gum_box_truth_view
    protocol = GraspsProtocol(episodes=2, fingers=2, turns_deg=(0.0, 90.0, 180.0, 270.0))
    grasps = grasp_candidates(jax.random.key(3), obj, protocol, np.repeat(np.arange(2), 6), np.tile(np.arange(6), 2))
    truth = simulate_two_sensor_grasps(jax.random.key(0), small_spec, obj, grasps.T_world_object, grasps.T_world_gripper)
    # Rays at every third pixel of the 60 x 80 px gel (pixel 3 i + 1: the ray grid's centres).
    settings = PredictionSettings(rows=20, cols=26)
    gel = (small_spec.height_px * small_spec.mm_per_px, small_spec.width_px * small_spec.mm_per_px)
    grid = map_marching_grid(view)
    predicted = jax.jit(jax.vmap(lambda T_wo, T_wg: predict_grasp(grid, view.surface, T_wo, T_wg, gel, settings)))(
        grasps.T_world_object, grasps.T_world_gripper)
    np.testing.assert_array_equal(np.asarray(predicted.valid), np.asarray(truth.valid))
    valid = np.flatnonzero(np.asarray(truth.valid))
    assert len(valid) >= 6
    true_opening = np.asarray(truth.imprint.opening[:, 0])[valid]
    assert np.median(np.abs(np.asarray(predicted.opening)[valid] - true_opening)) < 1.0
    ious, rmses = [], []
    for i in valid:
        rigid = np.asarray(truth.rigid_heightmap[i])[:, 1::3, 1::3][:, :20, :26]
        height = np.asarray(predicted.heightmap[i])
        felt, said = rigid > 1e-3, height > 1e-3
        ious.append((felt & said).sum() / (felt | said).sum())
        rmses.append(np.sqrt(np.mean((rigid - height)[felt | said] ** 2)))
    assert np.median(ious) > 0.5
    assert np.median(rmses) < 0.45
    # The prediction is of the map, not a copy of the truth: a shifted object changes it.
    shifted = predict_grasp(grid, view.surface, jax.tree.map(lambda x: x[valid[0]], grasps.T_world_object)
                            @ jaxlie.SE3.from_translation(np.array([0.0, 0.0, 3.0], np.float32)),
                            jax.tree.map(lambda x: x[valid[0]], grasps.T_world_gripper), gel, settings)
    assert not np.allclose(np.asarray(shifted.heightmap), np.asarray(predicted.heightmap[valid[0]]))
