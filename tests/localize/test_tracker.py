"""Tracking between touches: track_pose against the true pose of a synthetic surface, and the
tracking settings. (The Tracker on live frames, which starts from the localizer's belief, is
tested with the Localizer in test_localizer.py: one module builds their shared programs.)"""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax.localize import Touch, TrackingSettings
from tactojax.localize._tracker import track_pose as _track_pose
from tactojax.localize._tracker import tracking_starts

track_pose = jax.jit(_track_pose, static_argnames=("tracking", "settings", "points_per_touch"))
"""Jitted once per setting (faster than op by op), shared by the tests."""


def _touch(synthetic, T):
    heightmap, mask = synthetic.render(synthetic.bumps, T)
    return Touch(heightmap=jnp.asarray(heightmap), mask=jnp.asarray(mask), feature=jnp.zeros(()),
                 opening=jnp.float32(20.0))


def test_track_pose_follows_a_small_slip_between_map_imprints(bumps_view, synthetic):
    """Between grid imprints, 0.5 mm and 1 degree off: back to the true pose."""
    view = bumps_view
    for x, y, yaw in ((1.7, -1.2, 4.0), (-5.1, 2.4, -7.0)):
        T_true = synthetic.sensor_pose(x, y, yaw)
        T_previous = synthetic.sensor_pose(x + 0.4, y - 0.3, yaw + 1.0)
        estimate = track_pose(view, _touch(synthetic, T_true), T_previous)
        error = np.linalg.norm(np.asarray(estimate.T_object_sensor.translation() - T_true.translation()))
        start_error = np.linalg.norm(np.asarray(T_previous.translation() - T_true.translation()))
        assert error < 0.1 < start_error
        assert float(estimate.overlap) > 0.3 and int(estimate.imprint_index) >= 0  # (the second is at the map edge)


def test_track_pose_registers_only_against_imprints_facing_the_same_way(bumps_view, synthetic):
    """A pose looking up at the surface from below faces none of the map's imprints: no estimate."""
    upward = jaxlie.SE3.from_translation(jnp.array([0.0, 0.0, 0.2]))
    estimate = track_pose(bumps_view, _touch(synthetic, synthetic.sensor_pose(0.0, 0.0)), upward)
    assert int(estimate.imprint_index) == -1 and not bool(estimate.converged)


def test_more_neighbours_than_imprints_pads_with_unreal_ones(bumps_view, synthetic):
    """A map smaller than the neighbour count (the default tracking asks for 10; a coarse map may
    hold 8 imprints): every imprint, nearest first, then unreal slots, never an error."""
    count = len(bumps_view) + 5
    T = synthetic.sensor_pose(1.0, -2.0)
    centre = jnp.array([1.0, -2.0, 0.0], jnp.float32)
    nearest, real = bumps_view.imprints_near(T, centre, count)
    assert nearest.shape == real.shape == (count,)
    distance = np.linalg.norm(np.asarray(bumps_view.centres) - np.asarray(centre), axis=1)
    expected = np.argsort(distance, kind="stable")
    assert np.asarray(real).tolist() == [True] * len(bumps_view) + [False] * 5
    np.testing.assert_allclose(distance[np.asarray(nearest)[:len(bumps_view)]], distance[expected])


def test_tracking_settings_reject_bad_values():
    with pytest.raises(ValueError, match="neighbour"):
        TrackingSettings(neighbours=0)
    with pytest.raises(ValueError, match="max_facing_deg"):
        TrackingSettings(max_facing_deg=0.0)
    with pytest.raises(ValueError, match="max_residual_mm"):
        TrackingSettings(max_residual_mm=0.0)


def test_tracking_starts_are_the_previous_pose_the_prediction_and_in_plane_shifts():
    T_previous = jaxlie.SE3.exp(jnp.array([1.0, -2.0, 3.0, 0.1, 0.2, -0.3]))
    T_predicted = T_previous @ jaxlie.SE3.exp(jnp.array([0.3, 0.1, 0.0, 0.0, 0.0, 0.02]))
    starts = tracking_starts(T_previous, T_predicted, 1.5)
    np.testing.assert_allclose(np.asarray(starts.wxyz_xyz[0]), np.asarray(T_previous.wxyz_xyz), atol=1e-6)
    np.testing.assert_allclose(np.asarray(starts.wxyz_xyz[1]), np.asarray(T_predicted.wxyz_xyz), atol=1e-6)
    # The shifts, seen from the prediction: +-1.5 mm along the sensor's own x and y, no turn.
    relative = np.asarray(jax.vmap(lambda T: (T_predicted.inverse() @ jaxlie.SE3(T)).wxyz_xyz)(starts.wxyz_xyz[2:]))
    np.testing.assert_allclose(relative[:, :4], np.tile([1.0, 0, 0, 0], (4, 1)), atol=1e-5)
    np.testing.assert_allclose(relative[:, 4:], [[1.5, 0, 0], [-1.5, 0, 0], [0, 1.5, 0], [0, -1.5, 0]], atol=1e-4)
    assert tracking_starts(T_previous, T_predicted, 0.0).wxyz_xyz.shape == (2, 7)


def test_track_pose_predicts_with_the_last_motion(bumps_view, synthetic):
    """A slide that carries on: the prediction (previous pose moved as over the last frame)
    lands in ICP's basin where the previous pose alone is far."""
    view = bumps_view
    T_true = synthetic.sensor_pose(1.7, -1.2, 4.0)
    touch = _touch(synthetic, T_true)
    T_previous = synthetic.sensor_pose(1.7 - 6.0, -1.2, 4.0)
    motion = T_previous.inverse() @ synthetic.sensor_pose(1.7 + 0.3, -1.2, 4.0)  # lands 0.3 mm off
    settings = TrackingSettings(search_mm=0.0)
    estimate = track_pose(view, touch, T_previous, motion, tracking=settings)
    still = track_pose(view, touch, T_previous, jaxlie.SE3.identity(), tracking=settings)  # as None: no motion
    error = np.linalg.norm(np.asarray(estimate.T_object_sensor.translation() - T_true.translation()))
    still_error = np.linalg.norm(np.asarray(still.T_object_sensor.translation() - T_true.translation()))
    assert error < 0.1 < 1.0 < still_error


def test_tracking_settings_reject_bad_search_touch_size_and_iterations():
    with pytest.raises(ValueError, match="icp_iterations"):
        TrackingSettings(icp_iterations=0)
    with pytest.raises(ValueError, match="search_mm"):
        TrackingSettings(search_mm=-1.0)
    with pytest.raises(ValueError, match="min_relocalize_px"):
        TrackingSettings(min_relocalize_px=-1)
