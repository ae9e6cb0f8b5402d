"""Sensor presets: ``gelslim`` (parametric), ``gelsight`` and ``gelsight_mini`` (taxim calibrations)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from tactojax.sensor._spec import PhotometricOptics, PolynomialTableOptics, SensorSpec


def gelslim(*, scale: float = 1.0, noise_std: float = 0.01) -> SensorSpec:
    """A GelSlim-like finger sensor (the paper's sensor; the default).

    Assumptions, and why:
      * Field of view 32 x 24 mm imaged at 320 x 240 px, 0.1 mm/px. The GelSlim's gel pad is
        roughly this size (Donlon et al. 2018) and 0.1 mm/px resolves the paper's 0.06 mm depth
        errors as slopes over a few pixels.
      * Camera: the GelSlim's camera views the gel through a mirror at a shallow angle; after the
        four-corner homography rectification (``tactojax.hardware``) the image is an
        orthographic map of the gel at uniform mm/px, which is the model here.
      * Gel thickness 2.0 mm, elastic smoothing sigma 0.5 mm (a quarter of the thickness: the
        skirt around a contact spreads over about the gel thickness).
      * Optics: three coloured LEDs (red, green, blue) at 120 deg around the pad, 70 deg from
        the gel normal (grazing light, as in GelSight-family sensors), Lambertian membrane,
        vignetting that halves the signal at the corners, pixel noise 0.01 (about 2.5/255).

    Args:
        scale: resolution factor; 0.5 gives 160 x 120 px at 0.2 mm/px (same field of view).
        noise_std: camera noise, [0, 1] intensity units.
    """
    height_px, width_px = _scaled(240, 320, scale)
    return SensorSpec(
        name="gelslim",
        height_px=height_px,
        width_px=width_px,
        mm_per_px=0.1 * 320 / width_px,
        gel_thickness_mm=2.0,
        gel_smoothing_mm=0.5,
        noise_std=noise_std,
        optics=_gelslim_optics(height_px, width_px),
    )


def gelsight(*, scale: float = 1.0, noise_std: float = 0.005) -> SensorSpec:
    """GelSight with the real calibration from the ``taxim`` package (0.0295 mm/px, 480 x 640)."""
    return _taxim_preset("gelsight", scale=scale, noise_std=noise_std)


def gelsight_mini(*, scale: float = 1.0, noise_std: float = 0.005) -> SensorSpec:
    """GelSight Mini with the real calibration from the ``taxim`` package (0.0295 mm/px, 480 x 640)."""
    return _taxim_preset("gelsight_mini", scale=scale, noise_std=noise_std)


SENSOR_PRESETS = {"gelslim": gelslim, "gelsight": gelsight, "gelsight_mini": gelsight_mini}


def sensor_preset(name: str, *, scale: float = 1.0) -> SensorSpec:
    """A preset by name: one of ``SENSOR_PRESETS``."""
    if name not in SENSOR_PRESETS:
        raise ValueError(f"unknown sensor {name!r}; choose one of {sorted(SENSOR_PRESETS)}")
    return SENSOR_PRESETS[name](scale=scale)


def _scaled(height_px: int, width_px: int, scale: float) -> tuple[int, int]:
    if not 0 < scale <= 1:
        raise ValueError(f"scale must be in (0, 1], got {scale}")
    return max(8, round(height_px * scale)), max(8, round(width_px * scale))


def _gelslim_optics(height_px: int, width_px: int) -> PhotometricOptics:
    azimuths = np.deg2rad([90.0, 210.0, 330.0])
    polar = np.deg2rad(70.0)
    directions = np.stack(
        [np.sin(polar) * np.cos(azimuths), np.sin(polar) * np.sin(azimuths),
         -np.cos(polar) * np.ones(3)], axis=-1)
    colors = np.array([[0.95, 0.25, 0.20], [0.20, 0.90, 0.30], [0.20, 0.35, 1.00]])
    # Normalised image coordinates in [-1, 1] (x along columns, y along rows).
    u, v = np.meshgrid(np.linspace(-1, 1, width_px), np.linspace(-1, 1, height_px), indexing="xy")
    radius2 = (u**2 + v**2) / 2.0
    vignetting = 1.0 - 0.5 * radius2
    # Background: grey-blue membrane, each LED brightening the side it sits on.
    background = np.array([0.42, 0.44, 0.50]) * (1.0 - 0.25 * radius2)[..., None]
    for direction, color in zip(directions, colors):
        towards_light = (u * direction[0] + v * direction[1]) / np.sin(polar)
        background = background + 0.06 * color * (1.0 + towards_light)[..., None]
    return PhotometricOptics(
        background=jnp.asarray(np.clip(background, 0, 1), dtype=jnp.float32),
        vignetting=jnp.asarray(vignetting, dtype=jnp.float32),
        light_directions=jnp.asarray(directions, dtype=jnp.float32),
        light_colors=jnp.asarray(colors, dtype=jnp.float32),
        gain=1.0,
    )


@functools.lru_cache(maxsize=8)
def _taxim_preset(name: str, *, scale: float, noise_std: float) -> SensorSpec:
    from tactojax.storage import load_taxim_calibration

    calibration = load_taxim_calibration(name)
    full_height, full_width = calibration.background_rgb.shape[:2]
    height_px, width_px = _scaled(full_height, full_width, scale)
    background = jax.image.resize(
        jnp.asarray(calibration.background_rgb), (height_px, width_px, 3), "linear", antialias=True
    )
    return SensorSpec(
        name=name,
        height_px=height_px,
        width_px=width_px,
        mm_per_px=calibration.mm_per_px * full_width / width_px,
        gel_thickness_mm=1.5,
        gel_smoothing_mm=0.25,
        noise_std=noise_std,
        optics=PolynomialTableOptics(
            background=background,
            table=jnp.asarray(calibration.table_rgb),
            calibration_height_px=full_height,
            calibration_width_px=full_width,
        ),
    )
