"""Gaussian smoothing against scipy's reference."""

import jax
import numpy as np
import pytest
import scipy.ndimage

from tactojax.sensor import gaussian_blur


@pytest.mark.parametrize("sigma_px", [1.0, 2.0, 4.0])
def test_gaussian_blur_matches_scipy_with_zero_padding(sigma_px):
    image = np.random.default_rng(0).random((23, 31)).astype(np.float32)
    ours = np.asarray(jax.jit(gaussian_blur, static_argnums=1)(image, sigma_px))
    reference = scipy.ndimage.gaussian_filter(image.astype(np.float64), sigma_px, mode="constant", truncate=3.0)
    np.testing.assert_allclose(ours, reference, atol=1e-6)
