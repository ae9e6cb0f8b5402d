"""Ball-press calibration against closed-form spherical caps and a known colour model, and on real frames."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tactojax.sensor import PhotometricOptics, SensorSpec, render_image
from tactojax.shape._calibrate import (
    BallPresses,
    BallRadiusNotIdentifiableError,
    ball_press_data,
    best_mask_threshold,
    calibrate_from_presses,
    estimate_ball_radius,
    fit_sphere_cap,
    split_presses,
)
from tactojax.shape._metrics import heightmap_errors

BALL_RADIUS_MM = 2.0
MM_PER_PX = 0.05


def _lambertian_spec(height_px=120, width_px=160):
    """Three coloured lights 45 deg from the gel normal: colour change affine in the normal
    for tilts under 45 deg (no shadowing), weak enough not to clip."""
    azimuths = np.deg2rad([90.0, 210.0, 330.0])
    polar = np.deg2rad(45.0)
    directions = np.stack([np.sin(polar) * np.cos(azimuths), np.sin(polar) * np.sin(azimuths),
                           -np.cos(polar) * np.ones(3)], axis=-1)
    colors = 0.4 * np.array([[0.8, 0.2, 0.1], [0.1, 0.8, 0.2], [0.15, 0.2, 0.8]])
    optics = PhotometricOptics(
        background=jnp.full((height_px, width_px, 3), 0.45, jnp.float32),
        vignetting=jnp.ones((height_px, width_px), jnp.float32),
        light_directions=jnp.asarray(directions, jnp.float32), light_colors=jnp.asarray(colors, jnp.float32))
    return SensorSpec(name="lambertian", height_px=height_px, width_px=width_px, mm_per_px=MM_PER_PX,
                      gel_thickness_mm=2.0, gel_smoothing_mm=0.1, noise_std=0.0, optics=optics)


def _cap(shape, center, contact_radius_mm, ball_radius_mm, mm_per_px):
    """Closed-form cap heightmap, written out independently of the library."""
    rows, cols = np.indices(shape)
    rho2 = ((cols - center[0]) ** 2 + (rows - center[1]) ** 2) * mm_per_px**2
    depth_at_edge = np.sqrt(ball_radius_mm**2 - contact_radius_mm**2)
    return np.where(rho2 < contact_radius_mm**2, np.sqrt(np.maximum(ball_radius_mm**2 - rho2, 0)) - depth_at_edge, 0.0)


def _synthetic_presses(spec, ball_radius_mm, count, ratios, seed=0):
    """Presses of a ball rendered through ``spec``'s optics, 1/255 noise, uint8."""
    rng = np.random.default_rng(seed)
    mm_per_px = spec.mm_per_px
    render = jax.jit(render_image)
    images, centers, radii = [], [], []
    for _ in range(count):
        contact_px = ball_radius_mm * rng.uniform(*ratios) / mm_per_px
        center = (rng.uniform(contact_px + 2, spec.width_px - contact_px - 3),
                  rng.uniform(contact_px + 2, spec.height_px - contact_px - 3))
        heightmap = _cap(spec.shape, center, contact_px * mm_per_px, ball_radius_mm, mm_per_px)
        image = np.asarray(render(spec, jnp.asarray(heightmap, jnp.float32)))
        image = np.clip(image + rng.normal(0.0, 1.0 / 255, image.shape), 0.0, 1.0)
        images.append(np.round(image * 255).astype(np.uint8))
        centers.append(center)
        radii.append(contact_px)
    return BallPresses(background=np.asarray(spec.optics.background), images=np.stack(images),
                       centers_px=np.array(centers), radii_px=np.array(radii), mm_per_px=mm_per_px,
                       sensor=spec.name)


@pytest.fixture(scope="module")
def lambertian_presses():
    return _synthetic_presses(_lambertian_spec(), BALL_RADIUS_MM, 12, (0.5, 0.75))


def test_ball_press_data_is_the_spherical_cap():
    presses = BallPresses(background=np.zeros((21, 25, 3)), images=np.zeros((1, 21, 25, 3), np.uint8),
                          centers_px=[[12.0, 10.0]], radii_px=[8.0], mm_per_px=0.1)
    data = ball_press_data(presses, 1.0)
    # r = 0.8 mm on a 1 mm ball: depth 1 - 0.6 = 0.4 mm at the centre.
    assert data.heightmaps[0, 10, 12] == pytest.approx(0.4, abs=1e-6)
    # 0.5 mm to the right: sqrt(1 - 0.25) - 0.6.
    assert data.heightmaps[0, 10, 17] == pytest.approx(np.sqrt(0.75) - 0.6, abs=1e-6)
    assert data.heightmaps[0, 10, 20] == 0.0 and not data.masks[0, 10, 20]  # on the circle: outside
    rows, cols = np.indices((21, 25))
    assert data.masks[0].sum() == np.sum((cols - 12) ** 2 + (rows - 10) ** 2 < 64)
    assert np.all(data.heightmaps[0][~data.masks[0]] == 0) and data.object_ids.tolist() == ["ball"]


def test_impossible_ball_radius_and_bad_presses_are_clear_errors():
    good = dict(background=np.zeros((20, 20, 3)), images=np.zeros((1, 20, 20, 3), np.uint8),
                centers_px=[[10.0, 10.0]], radii_px=[5.0], mm_per_px=0.1)
    presses = BallPresses(**good)
    with pytest.raises(ValueError, match="not smaller than the ball radius"):
        ball_press_data(presses, 0.5)
    with pytest.raises(ValueError, match="ball radius must be positive"):
        ball_press_data(presses, -1.0)
    for change, message in [
        ({"radii_px": [10.0]}, "reaches outside"),
        ({"centers_px": [[18.0, 10.0]]}, "reaches outside"),
        ({"radii_px": [0.0]}, "radius positive"),
        ({"images": np.zeros((1, 20, 21, 3), np.uint8)}, "like the background"),
        ({"images": np.zeros((1, 20, 20, 3), np.float32)}, "uint8"),
        ({"images": np.zeros((0, 20, 20, 3), np.uint8), "centers_px": np.zeros((0, 2)), "radii_px": []},
         "no ball presses"),
        ({"radii_px": [5.0, 5.0]}, "radii"),
        ({"mm_per_px": 0.0}, "mm_per_px"),
    ]:
        with pytest.raises(ValueError, match=message):
            BallPresses(**{**good, **change})


def test_sphere_cap_fit_recovers_a_closed_form_cap():
    rng = np.random.default_rng(1)
    shape, center, mm_per_px = (60, 70), (33.3, 28.6), 0.05
    heightmap = _cap(shape, center, 1.2, 3.0, mm_per_px) + 0.1  # lifted by 0.1 mm everywhere
    radius, apex, residual = fit_sphere_cap(heightmap, center, 1.2 / mm_per_px, mm_per_px)
    assert radius == pytest.approx(3.0, rel=1e-4)
    assert apex == pytest.approx(3.0 - np.sqrt(9 - 1.44) + 0.1, abs=1e-5)
    assert residual < 1e-5
    noisy = heightmap + rng.normal(0, 0.005, shape)
    radius, _, residual = fit_sphere_cap(noisy, center, 1.2 / mm_per_px, mm_per_px)
    assert radius == pytest.approx(3.0, rel=0.03) and residual == pytest.approx(0.005, rel=0.1)


def test_mask_threshold_matches_a_loop_over_thresholds():
    rng = np.random.default_rng(2)
    heights = rng.uniform(0, 1, (3, 12, 14)).astype(np.float32)
    masks = rng.uniform(0, 1, (3, 12, 14)) < heights  # tall pixels tend to be in contact
    thresholds = np.linspace(0, 1, 17)
    best, ious = best_mask_threshold(heights, masks, thresholds)
    errors = jax.jit(heightmap_errors)
    expected = [np.mean([float(errors(h, h > t, h, m)["mask_iou"]) for h, m in zip(heights, masks)])
                for t in thresholds]
    np.testing.assert_allclose(ious, expected, atol=1e-6)
    assert best == thresholds[int(np.argmax(expected))]


def test_split_holds_out_every_fourth_press():
    train, held_out = split_presses(48, 0.25)
    assert held_out.tolist() == list(range(3, 48, 4)) and len(train) == 36
    with pytest.raises(ValueError, match="in \\(0, 1\\)"):
        split_presses(10, 1.0)
    with pytest.raises(ValueError, match="need at least 1 each"):
        split_presses(2, 0.25)


def test_estimate_recovers_the_radius_of_a_lambertian_gel(lambertian_presses):
    estimate, table = estimate_ball_radius(lambertian_presses)
    assert table["identifiable"]
    assert estimate == pytest.approx(BALL_RADIUS_MM, rel=0.03)
    assert table["lower_bound_mm"] == pytest.approx(lambertian_presses.contact_radii_mm.max())
    assert min(table["ball_radius_mm"]) > table["lower_bound_mm"]


def test_estimate_refuses_shallow_presses_and_free_form_colour():
    shallow = _synthetic_presses(_lambertian_spec(), BALL_RADIUS_MM, 8, (0.3, 0.45), seed=3)
    _, table = estimate_ball_radius(shallow)
    assert not table["identifiable"]  # a sphere of any large radius looks like a paraboloid
    pytest.importorskip("taxim")
    from tactojax.sensor import gelsight

    # The real GelSight colour table: colour is not affine in the normal.
    free_form = _synthetic_presses(gelsight(scale=0.25), 4.0, 8, (0.5, 0.75), seed=4)
    with pytest.raises(BallRadiusNotIdentifiableError, match="Measure the ball") as error:
        calibrate_from_presses(free_form)
    assert not error.value.table["identifiable"]


def test_calibration_reconstructs_held_out_presses(lambertian_presses):
    model, report = calibrate_from_presses(lambertian_presses, BALL_RADIUS_MM, bins=16)
    held_out = report["held_out"]
    assert report["held_out_presses"] == [3, 7, 11] and held_out["count"] == 3
    assert [row["press"] for row in held_out["presses"]] == [3, 7, 11]
    assert held_out["mean"]["fitted_radius_mm"] == pytest.approx(BALL_RADIUS_MM, rel=0.03)
    assert held_out["mean"]["cap_residual_rmse_mm"] < 0.02
    assert held_out["mean"]["ideal_cap_rmse_mm"] < 0.03
    assert held_out["mean"]["mask_iou"] > 0.9
    assert model.preset == "lookup" and model.mm_per_px == MM_PER_PX and not report["ball_radius_estimated"]


def _downscaled_taxim_presses(count, factor=2):
    """Every 4th real taxim GelSight press, block-averaged by ``factor`` (pixel centres rescaled)."""
    pytest.importorskip("taxim")
    from tactojax.io import load_taxim_calibration

    calibration = load_taxim_calibration("gelsight")
    rows = np.arange(0, 4 * count, 4)[:count]

    def shrink(image):
        height, width = image.shape[:2]
        return image.reshape(height // factor, factor, width // factor, factor, 3).mean(axis=(1, 3))

    images = np.stack([np.round(shrink(calibration.ball_frames_rgb[i].astype(np.float32))) for i in rows])
    return BallPresses(background=shrink(calibration.background_rgb), images=images.astype(np.uint8),
                       centers_px=(calibration.ball_centers_px[rows] + 0.5) / factor - 0.5,
                       radii_px=calibration.ball_radii_px[rows] / factor,
                       mm_per_px=calibration.mm_per_px * factor, sensor="gelsight")


def test_real_gelsight_presses_give_back_the_ball():
    presses = _downscaled_taxim_presses(12, factor=4)  # 120 x 160 px like the synthetic presses
    # Taxim calibrates this sensor with a 4 mm ball (Basics/sensorParams.py: ball_radius = 4.00/2).
    _, report = calibrate_from_presses(presses, 2.0, held_out_fraction=0.25)
    held_out = report["held_out"]
    assert held_out["count"] == 3
    assert held_out["mean"]["fitted_radius_mm"] == pytest.approx(2.0, rel=0.15)
    assert held_out["mean"]["cap_residual_rmse_mm"] < 0.2
    assert held_out["mean"]["mask_iou"] > 0.75
    # The real gel's colour is not affine in its normal: the presses cannot tell the radius.
    _, table = estimate_ball_radius(presses)
    assert not table["identifiable"] and table["lower_bound_mm"] == pytest.approx(presses.contact_radii_mm.max())


def test_take_keeps_the_background_and_pitch(lambertian_presses):
    subset = lambertian_presses.take(np.array([1, 4]))
    assert len(subset) == 2 and subset.mm_per_px == lambertian_presses.mm_per_px
    np.testing.assert_array_equal(subset.radii_px, lambertian_presses.radii_px[[1, 4]])
    assert dataclasses.replace(subset, sensor="x").sensor == "x"
