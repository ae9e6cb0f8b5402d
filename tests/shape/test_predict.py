"""predict: compiles once, vmaps like a loop, rejects wrong images; the lookup baseline works."""

import numpy as np
import pytest

from tactojax.shape import check_image, evaluate_shape_model, predict, predict_batch, split_held_out


def test_lookup_baseline_reconstructs_held_out_touches(shape_data, lookup_model):
    _, test = split_held_out(shape_data, 8)
    errors = evaluate_shape_model(lookup_model, test, batch_size=8)
    # Depths of 0.5-1.5 mm at 0.4 mm/px: the classical method is accurate to a few hundredths.
    assert np.nanmean(errors["patch_rmse"]) < 0.08
    assert np.mean(errors["mask_iou"]) > 0.6


def test_predict_batch_matches_a_loop_and_compiles_once(shape_data, lookup_model):
    images = shape_data.images_float(slice(0, 3))
    heightmaps, masks = predict_batch(lookup_model, images)
    before = predict._cache_size()
    for k in range(3):
        heightmap, mask = predict(lookup_model, images[k])
        np.testing.assert_allclose(heightmap, heightmaps[k], atol=1e-5)
        assert np.mean(np.asarray(mask) == np.asarray(masks[k])) > 0.999
        assert float(heightmap.min()) >= 0.0
    assert predict._cache_size() - before <= 1


def test_wrong_image_shape_is_a_clear_error(lookup_model):
    with pytest.raises(ValueError, match="does not match the shape model"):
        check_image(lookup_model, np.zeros((10, 10, 3)))
    check_image(lookup_model, np.zeros((2, *lookup_model.image_shape, 3)))
