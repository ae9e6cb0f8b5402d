"""The paper's one-touch baselines end to end on a synthetic map: semantics, accuracy, one compilation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tactojax.localize.baselines import IcpSettings, localize_baseline
from tactojax.localize._baselines import Method, _localize_baseline, parse_method
from tactojax.localize._evaluate import cloud_rmse
from tactojax.localize._map import map_touch
from tactojax.localize._points import contact_points
from tactojax.localize._retrieval import closest_imprints

SETTINGS = IcpSettings(iterations=20)
POINTS = 96


def _run(view, touch, method, key=0, exclude=-1):
    return localize_baseline(jax.random.key(key), view, touch, method=method, settings=SETTINGS,
                             points_per_touch=POINTS, exclude=exclude)


@pytest.fixture(scope="module")
def new_touch(synthetic):
    """A press between the map's presses (1.6 mm, 1.1 mm and 4 degrees off the nearest)."""
    T_true = synthetic.sensor_pose(1.6, -1.9, 4.0)
    return synthetic.touch(synthetic.bumps, T_true), T_true


def test_parse_method():
    assert parse_method("random") == Method("random", 0)
    assert parse_method("CTI") == Method("cti", 1)
    assert parse_method("cti-icp-5") == Method("cti-icp", 5)
    assert parse_method("belief") == Method("belief", 0)
    for bad in ["icp", "cti-icp-0", "cti-icp-", "cti-icp-x", "random-2", "cti-search-8", "cti-icp-multistart-3"]:
        with pytest.raises(ValueError, match="unknown localization method"):
            parse_method(bad)


def test_random_draws_stored_poses_but_never_the_excluded_one(bumps_view, bumps_map):
    touch = map_touch(bumps_view, 7)
    drawn = [int(_run(bumps_view, touch, "random", key, exclude=7).imprint_index) for key in range(40)]
    assert 7 not in drawn and len(set(drawn)) > 10
    estimate = _run(bumps_view, touch, "random", 3, exclude=7)
    np.testing.assert_allclose(np.asarray(estimate.T_object_sensor.wxyz_xyz),
                               np.asarray(bumps_map.T_object_sensor.wxyz_xyz[int(estimate.imprint_index)]))


def test_cti_returns_the_pose_of_the_closest_imprint(bumps_view, bumps_map):
    for k in [3, 12, 20]:
        touch = map_touch(bumps_view, k)
        expected, _, _ = closest_imprints(bumps_view.features, bumps_view.openings, bumps_view.imprint_valid,
                                          touch.feature, touch.opening, 1, exclude=k)
        estimate = _run(bumps_view, touch, "cti", exclude=k)
        assert int(estimate.imprint_index) == int(expected[0]) != k
        np.testing.assert_allclose(np.asarray(estimate.T_object_sensor.wxyz_xyz),
                                   np.asarray(bumps_map.T_object_sensor.wxyz_xyz[int(expected[0])]))


def test_cti_icp_localizes_a_new_touch(bumps_view, new_touch):
    touch, T_true = new_touch
    cti = _run(bumps_view, touch, "cti")
    estimate = _run(bumps_view, touch, "cti-icp-4")
    cloud, valid = contact_points(touch, bumps_view.mm_per_px, 128)
    assert float(cloud_rmse(cloud, valid, T_true, cti.T_object_sensor)) > 1.0
    assert float(cloud_rmse(cloud, valid, T_true, estimate.T_object_sensor)) < 0.05
    assert bool(estimate.converged) and float(estimate.overlap) > 0.8


def test_no_candidate_or_no_contact_gives_a_finite_failed_estimate(bumps_view, new_touch):
    touch, _ = new_touch
    no_contact = touch.replace(mask=jnp.zeros_like(touch.mask))
    for method in ["cti", "cti-icp-4"]:
        with pytest.raises(ValueError, match="no contact"):
            _run(bumps_view, no_contact, method)
        # Under vmap (a batch of touches) it cannot raise: the estimate fails, finite.
        for broken in [touch.replace(opening=jnp.float32(90.0)), no_contact]:
            estimate = jax.vmap(lambda t: _run(bumps_view, t, method))(jax.tree.map(lambda x: x[None], broken))
            assert not bool(estimate.converged[0])
            assert np.all(np.isfinite(np.asarray(estimate.T_object_sensor.wxyz_xyz)))
            assert np.isfinite(float(estimate.score[0]))
    with pytest.raises(ValueError, match="not a one-touch baseline"):
        _run(bumps_view, touch, "belief")


def test_repeated_calls_do_not_recompile(bumps_view):
    _run(bumps_view, map_touch(bumps_view, 0), "cti-icp-4", 0, exclude=0)
    before = _localize_baseline._cache_size()
    for k in range(1, 6):  # other touches, keys and exclusions: same shapes, no new compilation
        estimate = _run(bumps_view, map_touch(bumps_view, k), "cti-icp-4", k, exclude=k)
    jax.block_until_ready(estimate)
    assert _localize_baseline._cache_size() == before
