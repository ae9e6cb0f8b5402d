"""Tracking between touches: track_pose against the true pose of a synthetic surface, and the
Tracker's bookkeeping (first touch re-localized, then followed; contact lost ends the track)."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax._compilation import CompilationCounter
from tactojax.features import encode_images
from tactojax.io import load_encoder
from tactojax.localize import LocalizationMap, Localizer, Query, Tracker, TrackingSettings, track_pose, tracking_starts


def test_track_pose_follows_a_small_slip_between_map_imprints(bumps_map, synthetic):
    """Between grid imprints, 0.5 mm and 1 degree off: back to the true pose."""
    view = LocalizationMap.from_tactile_map(bumps_map)
    for x, y, yaw in ((1.7, -1.2, 4.0), (-5.1, 2.4, -7.0)):
        T_true = synthetic.sensor_pose(x, y, yaw)
        heightmap, mask = synthetic.render(synthetic.bumps, T_true)
        query = Query(heightmap=jnp.asarray(heightmap), mask=jnp.asarray(mask), feature=jnp.zeros(()),
                      opening=jnp.float32(20.0))
        T_previous = synthetic.sensor_pose(x + 0.4, y - 0.3, yaw + 1.0)
        estimate = track_pose(view, query, T_previous)
        error = np.linalg.norm(np.asarray(estimate.T_object_sensor.translation() - T_true.translation()))
        start_error = np.linalg.norm(np.asarray(T_previous.translation() - T_true.translation()))
        assert error < 0.1 < start_error
        assert float(estimate.overlap) > 0.3 and int(estimate.imprint_index) >= 0  # (the second is at the map edge)


def test_track_pose_registers_only_against_imprints_facing_the_same_way(bumps_map, synthetic):
    """A pose looking up at the surface from below faces none of the map's imprints: no estimate."""
    view = LocalizationMap.from_tactile_map(bumps_map)
    heightmap, mask = synthetic.render(synthetic.bumps, synthetic.sensor_pose(0.0, 0.0))
    query = Query(heightmap=jnp.asarray(heightmap), mask=jnp.asarray(mask), feature=jnp.zeros(()),
                  opening=jnp.float32(20.0))
    upward = jaxlie.SE3.from_translation(jnp.array([0.0, 0.0, 0.2]))
    estimate = track_pose(view, query, upward)
    assert int(estimate.imprint_index) == -1 and not bool(estimate.converged)


def test_tracking_settings_reject_bad_values():
    with pytest.raises(ValueError, match="neighbour"):
        TrackingSettings(neighbours=0)
    with pytest.raises(ValueError, match="max_facing_deg"):
        TrackingSettings(max_facing_deg=0.0)
    with pytest.raises(ValueError, match="max_residual_mm"):
        TrackingSettings(max_residual_mm=0.0)


@pytest.fixture(scope="module")
def tracker(cylinder_map, gum_box_map, lookup_model, tiny_encoder_path):
    encoder = load_encoder(tiny_encoder_path)
    maps = [m.with_features(encode_images(encoder, m.images)) for m in (cylinder_map, gum_box_map)]
    return Tracker(maps, lookup_model, encoder, method="cti-icp-2"), maps, encoder


def test_tracker_relocalizes_the_first_touch_then_follows(tracker, lookup_model):
    tracker, maps, encoder = tracker
    localizer = Localizer(maps, lookup_model, encoder, method="cti-icp-2")
    index = int(np.flatnonzero(np.asarray(maps[1].imprint_valid))[0])
    image, opening = np.asarray(maps[1].images[index]), float(maps[1].openings[index])
    background = np.round(np.asarray(lookup_model.background) * 255).astype(np.uint8)

    tracker.reset()
    first = tracker(image, opening)
    reference = localizer(image, opening)  # the first touch: exactly what the localizer says
    assert not first.tracked and first.object_id == reference.object_id
    np.testing.assert_allclose(np.asarray(first.T_object_sensor.wxyz_xyz),
                               np.asarray(reference.T_object_sensor.wxyz_xyz), atol=2e-3)
    assert tracker.following
    with CompilationCounter() as compiles:
        again = tracker(image, opening)  # the same touch again: followed, the pose stays
        gone = tracker(background, opening)  # contact lost: no estimate, the track ends
    assert compiles.messages == []
    assert again.tracked and again.object_id == first.object_id and again.similarity == first.similarity
    moved = np.linalg.norm(np.asarray(again.T_object_sensor.translation() - first.T_object_sensor.translation()))
    assert moved < 0.5
    assert not gone.contact and gone.T_object_sensor is None and not tracker.following
    assert not tracker(image, opening).tracked  # the next touch starts over
    assert again.as_dict()["tracked"] is True


def test_tracker_starts_from_a_given_pose_and_checks_it(tracker):
    tracker, maps, _ = tracker
    index = int(np.flatnonzero(np.asarray(maps[0].imprint_valid))[0])
    T_true = jaxlie.SE3(maps[0].T_object_sensor.wxyz_xyz[index])
    tracker.reset()
    tracker.start(maps[0].object_id, T_true)
    estimate = tracker(np.asarray(maps[0].images[index]), float(maps[0].openings[index]))
    assert estimate.tracked and estimate.object_id == maps[0].object_id
    assert np.linalg.norm(np.asarray(estimate.T_object_sensor.translation() - T_true.translation())) < 1.0
    with pytest.raises(ValueError, match="no map of 'banana'"):
        tracker.start("banana", T_true)
    with pytest.raises(ValueError, match="finite"):
        tracker.start(maps[0].object_id, jaxlie.SE3(jnp.full(7, jnp.nan)))


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


def test_track_pose_predicts_with_the_last_motion(bumps_map, synthetic):
    """A slide that carries on: the prediction (previous pose moved as over the last frame)
    lands in ICP's basin where the previous pose alone is far."""
    view = LocalizationMap.from_tactile_map(bumps_map)
    T_true = synthetic.sensor_pose(1.7, -1.2, 4.0)
    heightmap, mask = synthetic.render(synthetic.bumps, T_true)
    query = Query(heightmap=jnp.asarray(heightmap), mask=jnp.asarray(mask), feature=jnp.zeros(()),
                  opening=jnp.float32(20.0))
    T_previous = synthetic.sensor_pose(1.7 - 6.0, -1.2, 4.0)
    motion = T_previous.inverse() @ synthetic.sensor_pose(1.7 + 0.3, -1.2, 4.0)  # lands 0.3 mm off
    settings = TrackingSettings(search_mm=0.0)
    estimate = track_pose(view, query, T_previous, motion, tracking=settings)
    still = track_pose(view, query, T_previous, None, tracking=settings)
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
