"""The localization methods end to end on a synthetic map: semantics, accuracy, one compilation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tactojax.localize import (IcpSettings, LocalizationMap, Method, Query, closest_imprints, localize, map_query,
                               parse_method, query_points)
from tactojax.localize._evaluate import cloud_rmse
from tactojax.localize._methods import _localize

SETTINGS = IcpSettings(iterations=20)
POINTS = 96


def _run(view, query, method, key=0, exclude=-1):
    return localize(jax.random.key(key), view, query, method=method, settings=SETTINGS, points_per_query=POINTS,
                    exclude=exclude)


@pytest.fixture(scope="module")
def view(bumps_map):
    return LocalizationMap.from_tactile_map(bumps_map)


@pytest.fixture(scope="module")
def new_touch(bumps_map, synthetic):
    """A press between the map's presses (1.6 mm, 1.1 mm and 4 degrees off the nearest)."""
    T_true = synthetic.sensor_pose(1.6, -1.9, 4.0)
    heightmap, mask = synthetic.render(synthetic.bumps, T_true)
    feature = synthetic.make_map(synthetic.bumps, [T_true]).features[0]
    return Query(heightmap=jnp.asarray(heightmap), mask=jnp.asarray(mask), feature=feature,
                 opening=jnp.float32(20.0)), T_true


def test_parse_method():
    assert parse_method("random") == Method("random", 0)
    assert parse_method("CTI") == Method("cti", 1)
    assert parse_method("cti-icp-5") == Method("cti-icp", 5)
    assert parse_method("cti-icp-multistart-3").name == "cti-icp-multistart-3"
    assert parse_method("cti-search-8") == Method("cti-search", 8)
    for bad in ["icp", "cti-icp-0", "cti-icp-", "cti-icp-x", "random-2"]:
        with pytest.raises(ValueError, match="unknown localization method"):
            parse_method(bad)


def test_random_draws_stored_poses_but_never_the_excluded_one(view, bumps_map):
    query = map_query(view, 7)
    drawn = [int(_run(view, query, "random", key, exclude=7).imprint_index) for key in range(40)]
    assert 7 not in drawn and len(set(drawn)) > 10
    estimate = _run(view, query, "random", 3, exclude=7)
    np.testing.assert_allclose(np.asarray(estimate.T_object_sensor.wxyz_xyz),
                               np.asarray(bumps_map.T_object_sensor.wxyz_xyz[int(estimate.imprint_index)]))


def test_cti_returns_the_pose_of_the_closest_imprint(view, bumps_map):
    for k in [3, 12, 20]:
        query = map_query(view, k)
        expected, _, _ = closest_imprints(view.features, view.openings, view.imprint_valid, query.feature,
                                          query.opening, 1, exclude=k)
        estimate = _run(view, query, "cti", exclude=k)
        assert int(estimate.imprint_index) == int(expected[0]) != k
        np.testing.assert_allclose(np.asarray(estimate.T_object_sensor.wxyz_xyz),
                                   np.asarray(bumps_map.T_object_sensor.wxyz_xyz[int(expected[0])]))


@pytest.mark.parametrize("method", ["cti-icp-4", "cti-search-4"])
def test_icp_methods_localize_a_new_touch(view, new_touch, method):
    query, T_true = new_touch
    cti = _run(view, query, "cti")
    estimate = _run(view, query, method)
    cloud, valid = query_points(query, view.mm_per_px, 128)
    assert float(cloud_rmse(cloud, valid, T_true, cti.T_object_sensor)) > 1.0
    assert float(cloud_rmse(cloud, valid, T_true, estimate.T_object_sensor)) < 0.05
    assert bool(estimate.converged) and float(estimate.overlap) > 0.8


def test_no_candidate_or_no_contact_gives_a_finite_failed_estimate(view, new_touch):
    query, _ = new_touch
    no_contact = query.replace(mask=jnp.zeros_like(query.mask))
    for method in ["cti", "cti-icp-4", "cti-search-4"]:
        with pytest.raises(ValueError, match="no contact"):
            _run(view, no_contact, method)
        # Under vmap (a batch of touches) it cannot raise: the estimate fails, finite.
        for broken in [query.replace(opening=jnp.float32(90.0)), no_contact]:
            estimate = jax.vmap(lambda q: _run(view, q, method))(jax.tree.map(lambda x: x[None], broken))
            assert not bool(estimate.converged[0])
            assert np.all(np.isfinite(np.asarray(estimate.T_object_sensor.wxyz_xyz)))
            assert np.isfinite(float(estimate.score[0]))


def test_repeated_calls_do_not_recompile(view, bumps_map):
    _run(view, map_query(view, 0), "cti-icp-4", 0, exclude=0)
    before = _localize._cache_size()
    for k in range(1, 6):  # other queries, keys and exclusions: same shapes, no new compilation
        estimate = _run(view, map_query(view, k), "cti-icp-4", k, exclude=k)
    jax.block_until_ready(estimate)
    assert _localize._cache_size() == before
