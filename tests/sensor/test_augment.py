"""Colour augmentation: range, shape, determinism, identity, and the documented formula in numpy."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tactojax.sensor import augment_colors

_augment_jit = jax.jit(augment_colors, static_argnames=("max_gain", "max_offset", "max_gamma"))


def _image(seed=0, shape=(24, 32, 3)):
    return jnp.asarray(np.random.default_rng(seed).uniform(0.0, 1.0, size=shape), jnp.float32)


@pytest.mark.parametrize("seed", range(4))
def test_range_and_shape(seed):
    image = _image(seed)
    # Extreme settings push values past both ends before the clip.
    for kwargs in ({}, {"max_gain": 0.9, "max_offset": 0.5, "max_gamma": 1.0}):
        out = np.asarray(_augment_jit(jax.random.key(seed), image, **kwargs))
        assert out.shape == image.shape and out.dtype == np.float32
        assert out.min() >= 0.0 and out.max() <= 1.0
        assert np.all(np.isfinite(out))


def test_deterministic_per_key():
    image = _image()
    a = np.asarray(_augment_jit(jax.random.key(3), image))
    b = np.asarray(_augment_jit(jax.random.key(3), image))
    c = np.asarray(augment_colors(jax.random.key(3), image))  # jit and eager agree
    d = np.asarray(_augment_jit(jax.random.key(4), image))
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(a, c, atol=1e-6)
    assert np.abs(a - d).max() > 1e-3  # another key, another augmentation


def test_zero_strength_is_identity():
    image = _image(1)
    out = np.asarray(_augment_jit(jax.random.key(0), image, max_gain=0.0, max_offset=0.0, max_gamma=0.0))
    # Pixels at exactly 0 are floored to 1e-6 (keeps the gamma's gradient finite).
    np.testing.assert_allclose(out, np.asarray(image), atol=1e-6)
    exact = jnp.asarray([[[0.0, 0.5, 1.0]]], jnp.float32)
    out = np.asarray(_augment_jit(jax.random.key(0), exact, max_gain=0.0, max_offset=0.0, max_gamma=0.0))
    np.testing.assert_allclose(out, np.asarray(exact), atol=1e-6)


def test_per_channel_gain_offset_gamma_model():
    """Each channel follows clip((g I + o) ** gamma) with one (g, o, gamma) per channel, in the
    documented ranges: recover them from three grey levels and check the whole image."""
    max_gain, max_offset, max_gamma = 0.15, 0.05, 0.15
    for seed in range(5):
        key = jax.random.key(seed)
        levels = np.array([0.3, 0.5, 0.7], np.float32)
        probe = jnp.asarray(np.broadcast_to(levels[:, None, None], (3, 1, 3)), jnp.float32)
        y = np.asarray(_augment_jit(key, probe), np.float64)[:, 0, :]  # (level, channel)
        for c in range(3):
            # y^(1/gamma) is affine in the level: find gamma by a 1-D search on the log scale.
            gammas = np.exp(np.linspace(-max_gamma, max_gamma, 3001))
            roots = y[:, c][None, :] ** (1.0 / gammas[:, None])
            best = np.argmin(np.abs(roots[:, 0] - 2 * roots[:, 1] + roots[:, 2]))
            gamma, root = gammas[best], roots[best]
            gain = (root[2] - root[0]) / (levels[2] - levels[0])
            offset = root[0] - gain * levels[0]
            assert 1 - max_gain - 1e-3 <= gain <= 1 + max_gain + 1e-3
            assert -max_offset - 1e-3 <= offset <= max_offset + 1e-3
            # The recovered per-channel model reproduces the whole augmented image.
            image = _image(seed)
            out = np.asarray(_augment_jit(key, image), np.float64)[..., c]
            shifted = np.clip(gain * np.asarray(image)[..., c] + offset, 1e-6, 1.0)
            np.testing.assert_allclose(out, np.clip(shifted**gamma, 0.0, 1.0), atol=2e-3)


def test_vmap_matches_loop():
    images = jnp.stack([_image(s) for s in range(3)])
    keys = jax.random.split(jax.random.key(9), 3)
    batched = jax.jit(jax.vmap(augment_colors))(keys, images)
    for i in range(3):
        single = _augment_jit(keys[i], images[i])
        np.testing.assert_allclose(np.asarray(batched[i]), np.asarray(single), atol=1e-6)


def test_differentiable_in_image():
    from jax.test_util import check_grads

    image = jnp.asarray(np.random.default_rng(2).uniform(0.2, 0.8, size=(6, 5, 3)), jnp.float32)
    key = jax.random.key(1)
    f = jax.jit(lambda im: jnp.sum(augment_colors(key, im) ** 2))
    check_grads(f, (image,), order=1, modes=["fwd", "rev"], eps=1e-3, atol=1e-2, rtol=1e-2)
