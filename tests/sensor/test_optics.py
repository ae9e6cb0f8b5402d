"""Optics: rendering against a numpy reference of the documented model, gradients, and the real
GelSight ball presses shipped with taxim."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from tactojax.sensor import gel_surface, gelslim, render_image

SPEC = gelslim(scale=0.25)  # 60 x 80 px at 0.4 mm/px
TINY = gelslim(scale=0.1)  # 24 x 32 px, for gradient checks

_render_jit = jax.jit(render_image)


def _grid(spec):
    x = (np.arange(spec.width_px) - (spec.width_px - 1) / 2) * spec.mm_per_px
    y = (np.arange(spec.height_px) - (spec.height_px - 1) / 2) * spec.mm_per_px
    return np.meshgrid(x, y, indexing="xy")


def _bump(spec, amplitude=0.4, width=2.5, centre=(1.0, -0.5)):
    x, y = _grid(spec)
    return amplitude * np.exp(-((x - centre[0]) ** 2 + (y - centre[1]) ** 2) / (2 * width**2))


def _numpy_photometric(spec, h):
    """The PhotometricOptics docstring's model, written out in numpy (float64)."""
    optics = spec.optics
    dh_drow, dh_dcol = np.gradient(np.asarray(h, np.float64), spec.mm_per_px)
    n = -np.stack([dh_dcol, dh_drow, np.ones_like(h)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)  # membrane normal facing the camera (-z)
    lights = np.asarray(optics.light_directions, np.float64)
    colors = np.asarray(optics.light_colors, np.float64)
    shading = np.maximum(n @ lights.T, 0.0) - np.maximum(lights @ [0.0, 0.0, -1.0], 0.0)
    signal = optics.gain * np.asarray(optics.vignetting)[..., None] * (shading @ colors)
    return np.clip(np.asarray(optics.background, np.float64) + signal, 0.0, 1.0)


def test_flat_heightmap_gives_background_exactly():
    for h in (jnp.zeros(SPEC.shape), jnp.full(SPEC.shape, 0.7)):  # flat at any depth
        image = np.asarray(_render_jit(SPEC, h))
        np.testing.assert_array_equal(image, np.asarray(SPEC.optics.background))


@pytest.mark.parametrize("jit", [False, True])
def test_photometric_matches_numpy_model(jit):
    h = _bump(SPEC) + 0.3 * np.maximum(0.0, 1.0 - np.hypot(*_grid(SPEC)) / 4.0)  # bump + cone
    image = (_render_jit if jit else render_image)(SPEC, jnp.asarray(h, jnp.float32))
    np.testing.assert_allclose(np.asarray(image), _numpy_photometric(SPEC, h), atol=2e-5)
    assert image.shape == SPEC.shape + (3,)
    assert float(jnp.min(image)) >= 0.0 and float(jnp.max(image)) <= 1.0


def test_photometric_light_directions():
    """A slope tilting the membrane normal towards light k brightens light k's colour the most."""
    optics = SPEC.optics
    x, y = _grid(SPEC)
    for k, light in enumerate(np.asarray(optics.light_directions)):
        # h = s . (x, y): normal -(s, 1)/norm; towards light k means -s along light's xy.
        s = -0.3 * light[:2] / np.linalg.norm(light[:2])
        h = s[0] * x + s[1] * y + 5.0
        image = np.asarray(_render_jit(SPEC, jnp.asarray(h, jnp.float32)))
        delta = (image - np.asarray(optics.background))[20:40, 30:50].mean((0, 1))
        dominant = int(np.argmax(np.asarray(optics.light_colors)[k]))
        assert np.argmax(delta) == dominant, (k, delta)


def test_render_vmap_matches_loop():
    hs = jnp.asarray(np.stack([_bump(SPEC, a) for a in (0.1, 0.3, 0.6)]), jnp.float32)
    batched = jax.jit(jax.vmap(render_image, in_axes=(None, 0)))(SPEC, hs)
    for i in range(3):
        np.testing.assert_allclose(np.asarray(batched[i]), np.asarray(_render_jit(SPEC, hs[i])), atol=1e-6)


def test_check_grads_render_wrt_heightmap():
    with jax.enable_x64(True):
        h = jnp.asarray(_bump(TINY, amplitude=0.3, width=1.5), jnp.float64)
        weights = jnp.asarray(np.random.default_rng(0).normal(size=TINY.shape + (3,)), jnp.float64)

        @jax.jit
        def loss(h_):
            return jnp.sum(render_image(TINY, h_) * weights)

        image = np.asarray(render_image(TINY, h))
        assert 0.0 < image.min() and image.max() < 1.0  # no clipping: smooth here
        check_grads(loss, (h,), order=1, modes=["rev"], eps=1e-5, atol=1e-5, rtol=1e-5)


# ---------------------------------------------------------------- real GelSight ball presses

FRAMES = (0, 8, 24, 36)
BALL_RADIUS_MM = 2.0
# Measured with this model at scale 0.5 (frames 0, 8, 24, 36): 0.91, 0.92, 0.88, 0.89.
MIN_CORRELATION = 0.7


@pytest.fixture(scope="module")
def taxim_setup():
    pytest.importorskip("taxim")
    from tactojax.io import load_taxim_calibration
    from tactojax.sensor import gelsight

    calibration = load_taxim_calibration("gelsight")
    spec = gelsight(scale=0.5)
    assert (spec.height_px, spec.width_px) == (240, 320)
    render = jax.jit(lambda rigid: render_image(spec, gel_surface(spec, rigid)))
    return calibration, spec, render


@jax.jit
def _render_bump(spec, rigid):
    """The same gel surface mirrored through the gel plane: every slope reversed."""
    return render_image(spec, -gel_surface(spec, rigid))


def _downsample(image):
    h, w, c = image.shape
    return image.reshape(h // 2, 2, w // 2, 2, c).mean((1, 3))


def _pearson(a, b) -> float:
    a = np.ravel(a) - np.mean(a)
    b = np.ravel(b) - np.mean(b)
    return float(a @ b / np.sqrt((a @ a) * (b @ b)))


def _ball_heightmap(spec, mm_per_px_full, cx, cy, contact_radius_px):
    """Sphere cap of a ball of radius BALL_RADIUS_MM whose contact radius is the annotated one."""
    # Half-resolution pixel centres in full-resolution pixel coordinates.
    cols = (np.arange(spec.width_px) + 0.5) * 2 - 0.5
    rows = (np.arange(spec.height_px) + 0.5) * 2 - 0.5
    X, Y = np.meshgrid(cols, rows, indexing="xy")
    R = BALL_RADIUS_MM
    a = contact_radius_px * mm_per_px_full
    depth = R - np.sqrt(R * R - a * a)
    r2 = ((X - cx) ** 2 + (Y - cy) ** 2) * mm_per_px_full**2
    cap = np.maximum(0.0, depth - (R - np.sqrt(np.maximum(R * R - r2, 0.0))))
    return jnp.asarray(np.where(r2 < R * R, cap, 0.0), jnp.float32), X, Y


@pytest.mark.parametrize("frame", FRAMES)
def test_gelsight_ball_press_resembles_real_frame(taxim_setup, frame):
    calibration, spec, render = taxim_setup
    background = np.asarray(spec.optics.background)
    real_background = _downsample(calibration.background_rgb)
    np.testing.assert_allclose(background, real_background, atol=0.03)  # same frame, resampled
    real = _downsample(calibration.ball_frames_rgb[frame].astype(np.float32) / 255.0) - real_background

    cx, cy = calibration.ball_centers_px[frame]  # (column x, row y), full resolution
    a = float(calibration.ball_radii_px[frame])
    rigid, X, Y = _ball_heightmap(spec, calibration.mm_per_px, cx, cy, a)
    window = (np.abs(X - cx) <= 2 * a) & (np.abs(Y - cy) <= 2 * a)
    ours = np.asarray(render(rigid)) - background

    overall = _pearson(ours[window], real[window])
    per_channel = [_pearson(ours[window][:, c], real[window][:, c]) for c in range(3)]
    assert overall > MIN_CORRELATION, (overall, per_channel)
    assert min(per_channel) > 0.6, per_channel
    # Similar contrast (the table's colour scale is right).
    ratio = ours[window].std() / real[window].std()
    assert 0.6 < ratio < 1.6, ratio

    # Controls: the same ball two radii off, red and blue swapped, and slopes reversed
    # (a bump instead of a dent: wrong table direction convention) all correlate far worse.
    wrong_rigid, _, _ = _ball_heightmap(spec, calibration.mm_per_px, cx + 2 * a, cy, a)
    wrong_place = _pearson((np.asarray(render(wrong_rigid)) - background)[window], real[window])
    swapped = _pearson(ours[window][:, ::-1], real[window])
    reversed_slopes = _pearson((np.asarray(_render_bump(spec, rigid)) - background)[window], real[window])
    print(f"frame {frame}: r={overall:.3f} per-channel={np.round(per_channel, 3).tolist()} "
          f"contrast={ratio:.2f} wrong-place={wrong_place:.3f} RB-swapped={swapped:.3f} "
          f"reversed-slopes={reversed_slopes:.3f}")
    for control in (wrong_place, swapped, reversed_slopes):
        assert control < 0.3 and control < overall - 0.5, (overall, wrong_place, swapped, reversed_slopes)
