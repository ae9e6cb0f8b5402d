"""Identification among maps: two distinct synthetic objects, padding of maps of different sizes."""

import jax.numpy as jnp
import numpy as np
import pytest

from tactojax.localize._identify import MapLibrary, evaluate_identification, identify


def test_two_objects_are_told_apart(bumps_map, ridges_map):
    smaller = ridges_map.subset(np.arange(20))  # maps of different sizes are padded
    result = evaluate_identification([bumps_map, smaller])
    assert result.object_ids == ("bumps", "ridges")
    assert len(result.true) == int(bumps_map.imprint_valid.sum()) + int(smaller.imprint_valid.sum())
    assert result.accuracy() == 1.0
    assert np.array_equal(result.confusion(), np.diag([int(bumps_map.imprint_valid.sum()),
                                                     int(smaller.imprint_valid.sum())]))
    summary = result.summary()
    assert summary["top1"] == 1.0 and summary["confusion"] == result.confusion().tolist()


def test_identify_respects_exclusion_and_the_opening_filter(bumps_map, ridges_map):
    library = MapLibrary.from_maps([bumps_map, ridges_map])
    feature, opening = bumps_map.features[4], bumps_map.openings[4]
    guess, best = identify(library, feature, opening)
    assert int(guess) == 0 and float(best[0]) > 0.999  # the imprint itself
    _, held_out = identify(library, feature, opening, exclude=jnp.array([4, -1]))
    assert float(held_out[0]) < 0.999
    _, none = identify(library, feature, jnp.float32(50.0))
    assert np.all(np.isneginf(np.asarray(none)))


def test_identify_similarities_are_cosine_similarities(bumps_map, ridges_map):
    from scipy.spatial.distance import cdist

    rng = np.random.default_rng(0)
    maps = [m.with_features(jnp.asarray(rng.normal(size=(len(m), 6)) * rng.uniform(0.1, 10.0, (len(m), 1)),
                                        jnp.float32)) for m in (bumps_map, ridges_map)]
    library = MapLibrary.from_maps(maps)
    query = jnp.asarray(rng.normal(size=6) * 3.0, jnp.float32)
    _, best = identify(library, query, jnp.float32(maps[0].openings[0]), max_opening_difference_mm=jnp.inf)
    expected = [np.max(1.0 - cdist(np.asarray(m.features, np.float64)[np.asarray(m.imprint_valid)],
                                   np.asarray(query, np.float64)[None], "cosine")) for m in maps]
    np.testing.assert_allclose(best, expected, atol=1e-6)


def test_the_least_probable_objects_drop_out_up_to_the_tolerance():
    from tactojax.localize._identify_episodes import likely_objects

    p = np.array([[0.5, 0.0004, 0.0005, 0.4991, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0]])
    # Least probable first: 0.0, 0.0004, 0.0005 (cumulative 0.0009 <= 0.001); then 0.4991 would exceed it.
    np.testing.assert_array_equal(likely_objects(p, 1e-3)[0], [True, False, False, True, False])
    assert likely_objects(p, 1e-3)[1].all()  # no map explains the touches: every map stays
    assert likely_objects(p, 0.0).all()
    np.testing.assert_array_equal(likely_objects(p[0], 0.6), [True, False, False, False, False])
    for tolerance in (-0.1, 1.0):
        with pytest.raises(ValueError, match="object_tolerance"):
            likely_objects(p, tolerance)


def test_pruned_probabilities_leave_a_dropped_map_out_of_the_later_grasps():
    from tactojax.localize._identify_episodes import object_probabilities, pruned_probabilities

    log_evidence = np.log(np.array([[0.6, 0.3999, 0.0001], [0.1, 0.1, 0.8]]))  # (G, M): the third map recovers
    pruned = pruned_probabilities(log_evidence, 1e-3)
    np.testing.assert_allclose(pruned[0], object_probabilities(log_evidence[0]))
    np.testing.assert_allclose(pruned[1], [0.5, 0.5, 0.0])  # dropped after grasp 1: out of play
    np.testing.assert_allclose(pruned_probabilities(log_evidence, 0.0), object_probabilities(log_evidence))


def test_the_maps_in_play_at_each_grasp_follow_from_the_probabilities():
    from tactojax.localize._identify_episodes import maps_in_play, pruned_probabilities

    log_evidence = np.log(np.array([[0.6, 0.3999, 0.0001], [0.1, 0.1, 0.8], [0.5, 0.2, 0.3]]))
    in_play = maps_in_play(pruned_probabilities(log_evidence, 1e-3), 1e-3)
    np.testing.assert_array_equal(in_play, [[True, True, True], [True, True, False], [True, True, False]])
    assert maps_in_play(pruned_probabilities(log_evidence, 0.0), 0.0).all()
