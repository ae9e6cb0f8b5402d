"""observed_contact against scipy: the mask kept within radius_mm of a clear colour change."""

import jax.numpy as jnp
import numpy as np
from scipy import ndimage

from tactojax.mapping import observed_contact
from tactojax.mapping._build import SIGNAL_THRESHOLD


def test_observed_contact_is_the_mask_within_a_square_dilation_of_the_colour_change():
    rng = np.random.default_rng(0)
    image = rng.random((60, 80, 3)) * (rng.random((60, 80, 1)) > 0.97)  # sparse colour changes
    mask = rng.random((60, 80)) > 0.3
    kept = observed_contact(jnp.asarray(image, jnp.float32), jnp.zeros((60, 80, 3)), jnp.asarray(mask), 0.4)
    change = ndimage.uniform_filter(image, size=(3, 3, 1), mode="constant")
    strong = np.abs(change).max(axis=-1) > SIGNAL_THRESHOLD
    size = 2 * round(3.0 / 0.4) + 1  # OBSERVATION_RADIUS_MM = 3 mm at 0.4 mm/px
    expected = mask & ndimage.binary_dilation(strong, structure=np.ones((size, size)))
    assert 0 < expected.sum() < mask.sum()
    np.testing.assert_array_equal(np.asarray(kept), expected)
