"""The touch a grasp would give, predicted from the map's surface, against the simulator's."""

import jax
import jaxlie
import numpy as np
import pytest

from tactojax.localize._predict_touch import _read
from tactojax.localize.active import (MarchingGrid, PredictionSettings, StackedMarchingGrids, map_marching_grid,
                                     predict_grasp)
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


def test_stacked_marching_grids_read_as_each_grid_alone(gum_box_truth_view):
    """A map's grid within StackedMarchingGrids (flat arrays shared with other maps' grids of
    other sizes) reads exactly as the grid alone, inside it and outside, and predicts the same touch."""
    own = map_marching_grid(gum_box_truth_view)
    small = MarchingGrid(distance=own.distance[:7, :5, :9], known=own.known[:7, :5, :9], origin=own.origin + 1.0,
                         pitch_mm=own.pitch_mm)
    grids = [small, own, small]
    stacked = StackedMarchingGrids.from_grids(grids)
    extent = np.asarray(own.origin) + np.array(own.distance.shape) * own.pitch_mm
    points = np.random.default_rng(0).uniform(np.asarray(own.origin) - 5.0, extent + 5.0, (2000, 3)).astype(np.float32)
    read = jax.jit(lambda stacked, m, p: _read(stacked.grid(m), p))
    for m, grid in enumerate(grids):
        for got, want in zip(read(stacked, m, points), _read(grid, points)):
            np.testing.assert_array_equal(got, want)
    assert read._cache_size() == 1  # one program for every grid
    gel = (40.0, 30.0)
    T_world_object = jaxlie.SE3.identity()
    centre = np.asarray(own.origin) + 0.5 * (extent - np.asarray(own.origin))
    T_world_gripper = jaxlie.SE3.from_rotation_and_translation(
        jaxlie.SO3.from_matrix(np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]], np.float32)), centre.astype(np.float32))
    alone = predict_grasp(own, gum_box_truth_view.surface, T_world_object, T_world_gripper, gel, PredictionSettings())
    within = predict_grasp(stacked.grid(1), gum_box_truth_view.surface, T_world_object, T_world_gripper, gel,
                           PredictionSettings())
    np.testing.assert_array_equal(np.asarray(within.heightmap), np.asarray(alone.heightmap))
    assert bool(within.valid) == bool(alone.valid)
