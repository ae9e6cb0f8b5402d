"""may_show_contact (host, OpenCV) against observed_contact / shows_contact (JAX): it may say
True where JAX finds no contact, never False where JAX finds some."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tactojax.mapping import may_show_contact, observed_contact, shows_contact
from tactojax.mapping._build import SIGNAL_THRESHOLD

MM_PER_PX = 0.2


def _background(rng, shape=(24, 32)) -> np.ndarray:
    """A smooth lit gel frame, float32 RGB in [0, 1], exactly representable in uint8."""
    y, x = np.mgrid[:shape[0], :shape[1]]
    base = 0.5 + 0.1 * np.sin(x / 7.0)[..., None] * np.array([1.0, 0.5, -0.5]) + 0.05 * (y / shape[0])[..., None]
    return (np.round(base * 255) / 255).astype(np.float32)


@jax.jit
def _jax_contact(image, background):
    """What the live loop computes when the shape model predicts contact everywhere."""
    pixels = image.astype(jnp.float32) / 255.0
    observed = observed_contact(pixels, background, jnp.ones(image.shape[:2], bool), MM_PER_PX)
    return shows_contact(pixels, background, observed)


def _frame(background, rng, amplitude: float, noise: float = 0.0) -> np.ndarray:
    """The background with camera noise and a 3x3 square whose colour changes by ``amplitude``
    at a random place (edges included): its 3x3 mean change is ``amplitude`` at the centre."""
    image = background + noise * rng.normal(size=background.shape).astype(np.float32)
    row, col = rng.integers(0, background.shape[0]), rng.integers(0, background.shape[1])
    image[max(row - 1, 0):row + 2, max(col - 1, 0):col + 2, rng.integers(0, 3)] += amplitude
    return np.clip(np.round(image * 255), 0, 255).astype(np.uint8)


def test_background_and_camera_noise_cannot_show_contact():
    rng = np.random.default_rng(0)
    background = _background(rng)
    assert not may_show_contact(np.round(background * 255).astype(np.uint8), background)
    assert not may_show_contact(_frame(background, rng, 0.0, noise=0.013), background)
    assert may_show_contact(_frame(background, rng, 0.3, noise=0.013), background)


@pytest.mark.parametrize("seed", range(3))
def test_never_rules_out_a_frame_that_shows_contact(seed):
    """Changes straddling the threshold: every frame JAX calls touched passes the host check,
    and the check rules out most frames clearly below it (it is not always True)."""
    rng = np.random.default_rng(seed)
    background = _background(rng)
    ruled_out = 0
    for amplitude in np.linspace(0.8, 1.2, 41) * SIGNAL_THRESHOLD:
        image = _frame(background, rng, float(amplitude))
        possible = may_show_contact(image, background)
        if bool(_jax_contact(image, background)):
            assert possible, f"amplitude {amplitude:.4f}: JAX finds contact, the host check rules it out"
        ruled_out += not possible
    assert ruled_out >= 15  # the frames clearly under the threshold (about half of them)
