"""Identification among maps: two distinct synthetic objects, padding of maps of different sizes."""

import jax.numpy as jnp
import numpy as np

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
