"""Tracking between touches: track_pose against the true pose of a synthetic surface, and the
Tracker's bookkeeping (first touch re-localized, then followed; contact lost ends the track)."""

import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax._compilation import CompilationCounter
from tactojax.features import encode_images
from tactojax.io import load_encoder
from tactojax.localize import LocalizationMap, Localizer, Query, Tracker, TrackingSettings, track_pose


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
