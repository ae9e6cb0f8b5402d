"""The classical colour -> slope lookup table against a known colour model."""

import numpy as np
import jax.numpy as jnp

from tactojax.shape import fit_lookup_table, lookup_slope


def _linear_colour(slope):
    """An invertible colour model: each slope maps to a unique colour change."""
    mixing = np.array([[0.20, -0.10], [-0.05, 0.25], [0.10, 0.10]])
    return slope @ mixing.T


def test_table_inverts_a_known_colour_model():
    rng = np.random.default_rng(0)
    slope = rng.uniform(-0.6, 0.6, size=(50_000, 2))
    table, color_range = fit_lookup_table(_linear_colour(slope), slope, bins=32)
    probe = rng.uniform(-0.5, 0.5, size=(10, 12, 2))
    recovered = lookup_slope(jnp.asarray(table), color_range, jnp.asarray(_linear_colour(probe), jnp.float32))
    # Trilinear interpolation of bin means: error well below the bin width in slope units.
    assert np.abs(np.asarray(recovered) - probe).max() < 0.05


def test_empty_bins_take_the_nearest_value():
    colour = np.array([[0.1, 0.1, 0.1]] * 10 + [[-0.1, -0.1, -0.1]] * 10)
    slope = np.array([[1.0, 0.0]] * 10 + [[-1.0, 0.0]] * 10)
    table, color_range = fit_lookup_table(colour, slope, bins=8, color_range=0.2)
    assert np.all(np.isfinite(table))
    assert table[7, 7, 7, 0] == 1.0 and table[0, 0, 0, 0] == -1.0


def test_no_pixels_is_an_error():
    import pytest

    with pytest.raises(ValueError, match="no calibration pixels"):
        fit_lookup_table(np.zeros((0, 3)), np.zeros((0, 2)))
