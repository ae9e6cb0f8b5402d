"""Calibrating the belief: the fit recovers the scales that generated what happened."""

import numpy as np
import pytest

from tactojax.localize import BeliefCalibration, fit_calibration
from tactojax.localize._calibrate import BeliefRecord, predict_within
from tactojax.localize._map import REFERENCE_CONTACT_MM2


def _synthetic_records(rng, temperature, exponent, count=3000, hypotheses=12, appearance=0.0):
    """Beliefs whose truth is drawn from the calibrated weights themselves: P(within 2 mm) of a
    perfectly calibrated belief, every hypothesis a distinct pose."""
    touches = rng.integers(1, 7, count)
    geometry = rng.normal(0.0, 40.0, (count, hypotheses)) * touches[:, None]
    similarity = rng.normal(0.0, 1.0, (count, hypotheses)) * touches[:, None] if appearance else np.zeros_like(geometry)
    scaled = touches[:, None] ** -exponent * (temperature * geometry + appearance * similarity)
    weights = np.exp(scaled - scaled.max(axis=1, keepdims=True))
    weights /= weights.sum(axis=1, keepdims=True)
    truth_index = np.array([rng.choice(hypotheses, p=w) for w in weights])
    truth = np.arange(hypotheses)[None, :] == truth_index[:, None]
    return BeliefRecord(geometry=geometry, similarity=similarity, valid=np.ones_like(truth),
                        touches=touches, contact_mm2=np.full(count, REFERENCE_CONTACT_MM2),
                        same_pose=np.broadcast_to(np.eye(hypotheses, dtype=bool), (count, hypotheses, hypotheses)),
                        truth=truth)


@pytest.mark.parametrize("temperature, exponent", [(0.02, 0.5), (0.1, 0.0)])
def test_fit_recovers_a_known_temperature(temperature, exponent):
    records = _synthetic_records(np.random.default_rng(1), temperature, exponent)
    fitted, report = fit_calibration(records)
    assert float(fitted.temperature) == pytest.approx(temperature, rel=0.25)
    assert float(fitted.fusion_exponent) == pytest.approx(exponent, abs=0.25)
    assert float(fitted.appearance) == 0.0 or report["loss"] > 0
    # Calibrated on its own data: the predicted probabilities match what happened, bin by bin.
    probability, happened = predict_within(records, fitted)
    bins = np.digitize(probability, [0.2, 0.4, 0.6, 0.8])
    for b in range(5):
        if np.sum(bins == b) >= 100:
            assert abs(probability[bins == b].mean() - happened[bins == b].mean()) < 0.06


def test_fit_recovers_the_weight_of_the_appearance():
    """Where the truth follows the appearance as well, the fit finds its weight relative to the
    geometry's temperature; leaving the appearance out puts less mass on the truth."""
    from tactojax.localize._calibrate import truth_log_loss, truth_probability

    records = _synthetic_records(np.random.default_rng(4), 0.02, 0.5, appearance=1.0)
    fitted, report = fit_calibration(records)
    assert float(fitted.appearance) / float(fitted.temperature) == pytest.approx(1.0 / 0.02, rel=0.35)
    assert float(fitted.temperature) == pytest.approx(0.02, rel=0.3)
    without = BeliefCalibration(temperature=fitted.temperature, appearance=np.float32(0.0),
                                fusion_exponent=fitted.fusion_exponent)
    assert truth_log_loss(truth_probability(records, without)) > report["truth_loss"] + 0.1


def test_a_kept_shape_fits_the_sharpness_and_never_moves_the_best_hypothesis():
    """With the shape given, the fit keeps its appearance-to-temperature ratio (so every belief's
    best hypothesis stays the one the given shape picks) and still finds the temperature that
    generated what happened."""
    from tactojax.localize._calibrate import _posterior

    records = _synthetic_records(np.random.default_rng(6), 0.02, 0.5, appearance=1.0)
    shape = BeliefCalibration(temperature=np.float32(0.5), appearance=np.float32(0.5 / 0.02),
                              fusion_exponent=np.float32(0.0))  # the true ratio, far too sharp
    fitted, _ = fit_calibration(records, shape)
    assert float(fitted.appearance) / float(fitted.temperature) == pytest.approx(1.0 / 0.02, rel=1e-5)
    assert float(fitted.temperature) == pytest.approx(0.02, rel=0.3)
    np.testing.assert_array_equal(_posterior(records, fitted)[1], _posterior(records, shape)[1])
    # A wrong shape is kept too: the best hypotheses stay its own, only the sharpness is fit.
    wrong = shape.replace(appearance=np.float32(0.0))
    kept, _ = fit_calibration(records, wrong)
    assert float(kept.appearance) == 0.0
    np.testing.assert_array_equal(_posterior(records, kept)[1], _posterior(records, wrong)[1])


def test_an_overconfident_temperature_is_worse_than_the_fit():
    records = _synthetic_records(np.random.default_rng(2), 0.02, 0.0)
    fitted, report = fit_calibration(records)
    hot = BeliefCalibration(temperature=np.float32(1.0), appearance=np.float32(0.0), fusion_exponent=np.float32(0.0))
    probability, happened = predict_within(records, hot)
    assert probability.mean() > happened.mean() + 0.2  # overconfident
    fitted_probability, _ = predict_within(records, fitted)
    assert abs(fitted_probability.mean() - happened.mean()) < 0.03


def _drop_truth(rng, records, offset, slope, contact=0.0):
    """The records with the truth removed (a search that missed it) at the rate
    1 - sigmoid(offset + slope * log touches + contact * log(area / reference area)), written
    out here, independently of the library's :func:`found_log_odds`."""
    log_area = np.log(records.contact_mm2 / REFERENCE_CONTACT_MM2)
    found = 1.0 / (1.0 + np.exp(-(offset + slope * np.log(records.touches) + contact * log_area)))
    missed = rng.random(found.shape) > found
    return records.replace(truth=records.truth & ~missed[:, None])


def test_fit_recovers_how_often_the_search_misses_the_truth():
    """Beliefs whose weights are calibrated when the truth is among the hypotheses, but whose
    search misses it more often after few touches: the fit recovers that rate, and the reported
    P(within 2 mm) matches what happened at every touch count."""
    from tactojax.localize.evaluation import fit_found_probability

    rng = np.random.default_rng(5)
    records = _drop_truth(rng, _synthetic_records(rng, 0.02, 0.5, count=6000), offset=0.0, slope=2.0)
    complete = BeliefCalibration(temperature=np.float32(0.02), appearance=np.float32(0.0),
                                 fusion_exponent=np.float32(0.5))
    fitted = fit_found_probability(records, complete)
    touches = np.array([1, 2, 6])
    expected = 1.0 / (1.0 + np.exp(-(0.0 + 2.0 * np.log(touches))))
    np.testing.assert_allclose(np.asarray(fitted.found_probability(touches)), expected, atol=0.05)
    probability, happened = predict_within(records, fitted)
    overconfident, _ = predict_within(records, complete)
    for count in (1, 2, 6):
        mask = records.touches == count
        assert abs(probability[mask].mean() - happened[mask].mean()) < 0.04
    assert overconfident[records.touches == 1].mean() > 1.5 * happened[records.touches == 1].mean()  # twice, in truth


def test_fit_recovers_how_the_contact_area_moves_the_missed_search():
    """The search misses the truth more often after small touches (log-odds growing by 1.5 per
    e-fold of contact area): the fit recovers that growth, and the reported P(within 2 mm) matches
    what happened for small and large touches alike, which a term of the touch count alone cannot
    (it is right on average and wrong on both halves)."""
    from tactojax.localize.evaluation import fit_found_probability

    rng = np.random.default_rng(11)
    records = _synthetic_records(rng, 0.02, 0.5, count=6000)
    records = records.replace(contact_mm2=np.exp(rng.uniform(np.log(0.5), np.log(200.0), 6000)))
    records = _drop_truth(rng, records, offset=1.0, slope=1.0, contact=1.5)
    complete = BeliefCalibration(temperature=np.float32(0.02), appearance=np.float32(0.0),
                                 fusion_exponent=np.float32(0.5))
    fitted = fit_found_probability(records, complete, contact=None)  # the growth fit too
    assert float(fitted.found_contact) == pytest.approx(1.5, abs=0.3)
    area_blind = fit_found_probability(records, complete, contact=0.0)
    assert float(area_blind.found_contact) == 0.0
    fixed = fit_found_probability(records, complete, contact=1.0)  # a growth given: offset and slope fit at it
    assert float(fixed.found_contact) == 1.0
    small = records.contact_mm2 < 5.0
    for calibration, tolerance in ((fitted, 0.03), (area_blind, None)):
        probability, happened = predict_within(records, calibration)
        gaps = [probability[part].mean() - happened[part].mean() for part in (small, ~small)]
        if tolerance is None:
            assert gaps[0] > 0.05 and gaps[1] < -0.05  # overconfident on small touches, under on large
        else:
            assert max(abs(g) for g in gaps) < tolerance
    # The probability the belief reports, in JAX, is the same function of the touches and the area.
    touches, area = np.array([1, 2, 6]), np.array([0.5, 20.0, 200.0])
    expected = 1.0 / (1.0 + np.exp(-(float(fitted.found_offset) + float(fitted.found_slope) * np.log(touches)
                                     + float(fitted.found_contact) * np.log(area / REFERENCE_CONTACT_MM2))))
    np.testing.assert_allclose(np.asarray(fitted.found_probability(touches, area)), expected, rtol=1e-5)


def test_search_only_keeps_the_scales_and_fits_the_missed_search():
    """``search_only``: the given scales stay exactly (even wrong ones), and the missed-search rate
    is recovered as by :func:`fit_found_probability` at those scales."""
    from tactojax.localize.evaluation import fit_found_probability

    rng = np.random.default_rng(7)
    records = _drop_truth(rng, _synthetic_records(rng, 0.02, 0.5, count=6000), offset=0.0, slope=2.0)
    kept = BeliefCalibration(temperature=np.float32(0.02), appearance=np.float32(0.0), fusion_exponent=np.float32(0.5))
    fitted, report = fit_calibration(records, kept, search_only=True)
    for name in ("temperature", "appearance", "fusion_exponent"):
        assert float(getattr(fitted, name)) == pytest.approx(float(getattr(kept, name)), rel=1e-6)
    touches = np.array([1, 2, 6])
    expected = 1.0 / (1.0 + np.exp(-(0.0 + 2.0 * np.log(touches))))
    np.testing.assert_allclose(np.asarray(fitted.found_probability(touches)), expected, atol=0.05)
    reference = fit_found_probability(records, kept)
    assert float(fitted.found_offset) == float(reference.found_offset)
    assert float(fitted.found_slope) == float(reference.found_slope)
    hot = kept.replace(temperature=np.float32(1.0))  # a wrong temperature is kept as well
    assert float(fit_calibration(records, hot, search_only=True)[0].temperature) == 1.0
    with pytest.raises(ValueError, match="search_only"):
        fit_calibration(records, search_only=True)


def test_a_fit_stored_before_the_search_term_takes_the_default_and_one_before_the_contact_term_none():
    from tactojax.localize import calibration_from_json, calibration_to_json
    from tactojax.localize._map import DEFAULT_FOUND

    old = {"temperature": 0.1, "appearance": 2.0, "fusion_exponent": 0.5, "loss": 0.3}
    calibration = calibration_from_json(old)
    assert float(calibration.found_offset) == pytest.approx(DEFAULT_FOUND["found_offset"])
    assert float(calibration.found_slope) == pytest.approx(DEFAULT_FOUND["found_slope"])
    assert float(calibration.found_contact) == pytest.approx(DEFAULT_FOUND["found_contact"])
    again = calibration_from_json(calibration_to_json(calibration.replace(found_offset=np.float32(-1.5))))
    assert float(again.found_offset) == -1.5 and float(again.temperature) == pytest.approx(0.1)
    # A search term fit before the contact area entered it was fit without it: it reads as a growth of 0.
    before_contact = calibration_from_json({**old, "found_offset": 1.0, "found_slope": 2.0})
    assert float(before_contact.found_contact) == 0.0 and float(before_contact.found_offset) == 1.0


def test_nothing_to_fit_is_a_clear_error():
    records = _synthetic_records(np.random.default_rng(3), 0.1, 0.0, count=5)
    records = records.replace(valid=np.zeros_like(records.valid))
    with pytest.raises(ValueError, match="no calibration touch"):
        fit_calibration(records)


def test_reliability_tells_chance_gaps_from_miscalibration():
    """A calibrated predictor's largest bin gap is within what chance gives it; an overconfident
    one's is not. The bins match a direct count. The gap the tables print is the one over the bins
    of >= 10 beliefs: a bin of one belief does not set it."""
    from tactojax.localize.evaluation import calibration, calibration_gap

    rng = np.random.default_rng(1)
    predicted = rng.random(400)
    honest = calibration(predicted, rng.random(400) < predicted)
    overconfident = calibration(predicted, rng.random(400) < 0.5 * predicted)
    assert honest["calibrated_p"] > 0.05 and honest["max_gap_binned"] <= honest["calibrated_max_gap_95"] + 1e-9
    assert overconfident["calibrated_p"] < 0.01 and overconfident["max_gap_binned"] > 0.15
    happened = rng.random(400) < predicted
    table = calibration(predicted, happened)
    for row in table["bins"]:
        lo, hi = row["bin"]
        inside = (predicted >= lo) & ((predicted < hi) if hi < 1.0 else (predicted <= hi))
        assert row["count"] == inside.sum()
        assert row["observed"] == pytest.approx(happened[inside].mean())
    few = calibration(predicted[:5], happened[:5])
    assert few["max_gap_binned"] is None and few["calibrated_p"] is None and calibration_gap(few) == "-"
    # Twenty beliefs saying 0.1 (two right) and one saying 0.9 that was wrong: 0.9 over every bin, 0.0 over the full one.
    lonely = calibration(np.r_[np.full(20, 0.1), 0.9], np.r_[np.arange(20) < 2, False])
    assert lonely["max_gap"] == pytest.approx(0.9) and lonely["max_gap_binned"] == pytest.approx(0.0, abs=1e-12)
    assert calibration_gap(lonely) == f"0.00 (p {lonely['calibrated_p']:.2f})"
