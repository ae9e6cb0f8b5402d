"""Heightmap error metrics against a direct numpy computation."""

import numpy as np

from tactojax.shape import batch_heightmap_errors, heightmap_errors, summarize_errors


def test_against_numpy():
    rng = np.random.default_rng(0)
    true = rng.uniform(0, 1, (4, 6, 7)).astype(np.float32)
    predicted = true + rng.normal(0, 0.1, true.shape).astype(np.float32)
    true_mask = true > 0.5
    predicted_mask = predicted > 0.5
    errors = batch_heightmap_errors(predicted, predicted_mask, true, true_mask)
    for k in range(4):
        squared = (predicted[k] - true[k]) ** 2
        np.testing.assert_allclose(errors["patch_rmse"][k], np.sqrt(squared[true_mask[k]].mean()), rtol=1e-5)
        np.testing.assert_allclose(errors["image_rmse"][k], np.sqrt(squared.mean()), rtol=1e-5)
        iou = (predicted_mask[k] & true_mask[k]).sum() / (predicted_mask[k] | true_mask[k]).sum()
        np.testing.assert_allclose(errors["mask_iou"][k], iou, rtol=1e-5)


def test_empty_patch_and_summary():
    zeros = np.zeros((3, 3), np.float32)
    empty = np.zeros((3, 3), bool)
    errors = heightmap_errors(zeros, empty, zeros, empty)
    assert np.isnan(errors["patch_rmse"]) and float(errors["mask_iou"]) == 1.0
    summary = summarize_errors({"patch_rmse": np.array([1.0, np.nan, 3.0])}, np.array(["a", "a", "b"]))
    assert summary["a"]["patch_rmse"] == 1.0 and summary["all"]["patch_rmse"] == 2.0
    assert summary["all"]["count"] == 3
