"""New grasps: the evaluation's single touches, fused episodes and calibration records agree with one another."""

import jax
import jaxlie
import numpy as np
import pytest

from tactojax.localize import empty_belief
from tactojax.localize._calibrate import predict_within
from tactojax.localize.evaluation import belief_error, evaluate_new_grasps, record_beliefs


@pytest.mark.slow  # ~1 min on 2 cores; tests/cli/test_belief_cli.py runs the evaluation and the calibration
def test_single_touches_fused_episodes_and_calibration_records_agree(bumps_view, bumps_episodes, belief_settings):
    episodes = bumps_episodes  # two episodes of two grasps, one finger
    single, *fused = evaluate_new_grasps(bumps_view, episodes, ("belief",), settings=belief_settings)
    assert (single.grasps, single.fused) == (1, False) and [f.grasps for f in fused] == [1, 2]
    assert single.rmse.shape == (4,) and all(f.rmse.shape == (2,) for f in fused)
    # Every touch is found (the map holds the surface around it), and the belief knows it.
    assert np.all(single.rmse < 0.5) and np.all(fused[1].rmse < 0.5)
    # (P(within 2 mm) is the mass near the best times the map's P(the search found the truth's
    # mode) after one touch.)
    found = float(bumps_view.calibration.found_probability(1))
    assert np.all(single.probability > 0.5 * found) and np.all(single.covered)
    # An episode's first grasp alone (one finger) is its first single touch: the same belief.
    np.testing.assert_array_equal(fused[0].rmse, single.rmse[::2])
    np.testing.assert_array_equal(fused[0].probability, single.probability[::2])
    summary = fused[1].summary()
    assert summary["count"] == 2 and summary["within_mm"]["2"] == 1.0 and "calibration" in summary

    # Calibration records, touch by touch then each later grasp alone: under the map's own
    # calibration they predict exactly the beliefs' P(within 2 mm).
    records = record_beliefs(bumps_view, episodes, fingers=1, settings=belief_settings)
    assert records.valid.shape == (2 * 3, belief_settings.hypotheses)
    predicted, happened = predict_within(records, bumps_view.calibration)
    expected = np.stack([fused[0].probability, fused[1].probability, single.probability[1::2]], axis=1).reshape(-1)
    np.testing.assert_allclose(predicted, expected, atol=1e-4)
    assert np.all(happened)  # every best hypothesis is within 2 mm of the truth


@pytest.mark.slow  # ~1 min on 2 cores
def test_a_touch_without_contact_is_no_estimate_not_a_perfect_one(bumps_view, bumps_episodes, belief_settings):
    """Without contact the belief has no estimate; its placeholder pose (the identity) is the
    truth in the evaluation's object frame, so it must count as a failure, not an error of 0."""
    blank = bumps_episodes.masks.at[1, 0].set(False)  # the second episode's first grasp felt nothing
    episodes = bumps_episodes.replace(masks=blank)
    single, first, both = evaluate_new_grasps(bumps_view, episodes, ("belief",), settings=belief_settings)
    assert np.isinf(single.rmse[2]) and single.probability[2] == 0.0
    assert np.all(np.isfinite(np.delete(single.rmse, 2)))
    assert np.isinf(first.rmse[1]) and np.isfinite(both.rmse[1])  # the second grasp has contact
    summary = single.summary()
    assert summary["no_estimate"] == 1 and summary["within_mm"]["2"] == 0.75
    assert summary["per_localization"]["rmse_mm"][2] is None


def test_belief_error_of_a_belief_without_estimate_is_infinite(bumps_view, belief_settings):
    belief = empty_belief(bumps_view, belief_settings)
    assert np.isinf(float(jax.jit(belief_error)(belief, jaxlie.SE3.identity())))
