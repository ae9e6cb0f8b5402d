"""The fast heightmap formulation (issue 17) against the one it replaced, kept here as reference.

The reference is the math ``SlopePoissonNet`` used to run: patches as a convolution with an
identity kernel, a stack of ``nn.Dense`` on channels-last pixels, the Poisson solve with
``jax.scipy.fft.dctn``, and the background level as ``jnp.quantile`` (a sort). The library
now computes the same with cheaper kernels; outputs agree to float32 round-off.
"""

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.scipy.fft import dctn, idctn

from tactojax.io import resolve_shape_model
from tactojax.sensor import add_sensor_noise, gelslim, render_image
from tactojax.shape import (ShapeModel, build_network, coordinate_bias, init_shape_model, integrate_gradient,
                            predict, predict_batch, zero_background)
from tactojax.shape._models import MASK_SHARPNESS_MM, SlopePoissonNet, patch_planes, pixel_patches
from tactojax.shape._predict import network_input, raw_prediction
from tactojax.shape._quantile import (order_statistics, order_statistics_by_bisection, order_statistics_by_comparison,
                                      order_statistics_by_sort, quantile)


# --- the reference: the replaced formulation --------------------------------------------------

def reference_patches(x):
    """(H, W, C) -> (H, W, 9C) by ``conv_general_dilated_patches``."""
    return jax.lax.conv_general_dilated_patches(
        x[None], (3, 3), (1, 1), "SAME", dimension_numbers=("NHWC", "OIHW", "NHWC"))[0]


class ReferenceSlopeNet(nn.Module):
    """The replaced slope MLP: nn.Dense layers on channels-last features."""

    features: int
    hidden_layers: int

    @nn.compact
    def __call__(self, patches):
        hidden = nn.relu(nn.Dense(self.features)(patches))
        for _ in range(self.hidden_layers):
            hidden = nn.relu(nn.Dense(self.features)(hidden))
        return nn.Dense(2)(hidden)


def reference_integrate(slope, mm_per_px):
    """Poisson integration with jax.scipy.fft's DCT."""
    height_px, width_px = slope.shape[:2]
    step_x = 0.5 * (slope[:, 1:, 0] + slope[:, :-1, 0]) * mm_per_px
    step_y = 0.5 * (slope[1:, :, 1] + slope[:-1, :, 1]) * mm_per_px
    rhs = (jnp.pad(step_x, ((0, 0), (1, 0))) - jnp.pad(step_x, ((0, 0), (0, 1)))
           + jnp.pad(step_y, ((1, 0), (0, 0))) - jnp.pad(step_y, ((0, 1), (0, 0))))
    eig_x = 4.0 * jnp.sin(jnp.pi * jnp.arange(width_px) / (2 * width_px)) ** 2
    eig_y = 4.0 * jnp.sin(jnp.pi * jnp.arange(height_px) / (2 * height_px)) ** 2
    eigenvalues = eig_y[:, None] + eig_x[None, :]
    coefficients = dctn(rhs, type=2, norm="ortho")
    coefficients = jnp.where(eigenvalues > 0, coefficients / jnp.where(eigenvalues > 0, eigenvalues, 1.0), 0.0)
    return idctn(coefficients, type=2, norm="ortho")


class ReferenceSlopePoissonNet(nn.Module):
    """The replaced ``SlopePoissonNet``: same parameters, the old kernels."""

    features: int
    hidden_layers: int
    mm_per_px: float
    background_quantile: float = 0.1

    def setup(self):
        self.slope_net = ReferenceSlopeNet(self.features, self.hidden_layers)
        self.mask_threshold_mm = self.param("mask_threshold_mm", nn.initializers.constant(0.1), ())

    def __call__(self, x):
        slope = self.slope_net(reference_patches(x))
        heightmap = reference_integrate(slope, self.mm_per_px)
        heightmap = heightmap - jnp.quantile(heightmap, self.background_quantile)
        return jnp.stack([heightmap, (heightmap - self.mask_threshold_mm) / MASK_SHARPNESS_MM], axis=-1)


def reference_network(preset: str, mm_per_px: float) -> ReferenceSlopePoissonNet:
    network = build_network(preset, mm_per_px)
    return ReferenceSlopePoissonNet(network.features, network.hidden_layers, mm_per_px)


def reference_predict(model: ShapeModel, image):
    """``predict`` of a ``fast``/``tiny`` model as it used to be computed."""
    inputs = network_input(image, model.background, model.preset, model.color_gain)
    output = reference_network(model.preset, model.mm_per_px).apply({"params": model.params}, inputs)
    return jnp.maximum(output[..., 0], 0.0), output[..., 1] > 0.0


# --- fixtures ------------------------------------------------------------------------------------

def _sphere_press(shape, depth_mm, mm_per_px):
    """(H, W) heightmap, mm: a sphere pressed ``depth_mm`` deep off the image centre."""
    height_px, width_px = shape
    rows, cols = np.mgrid[:height_px, :width_px] * mm_per_px
    centre = np.array([0.45 * height_px, 0.55 * width_px]) * mm_per_px
    radius = 0.3 * min(height_px, width_px) * mm_per_px
    distance2 = (rows - centre[0]) ** 2 + (cols - centre[1]) ** 2
    return np.maximum(depth_mm * (1.0 - distance2 / radius**2), 0.0)


def _press(background, depth_mm, mm_per_px, seed):
    """A made-up image of a sphere press: the background plus a colour change along the slope."""
    slope_y, slope_x = np.gradient(_sphere_press(background.shape[:2], depth_mm, mm_per_px), mm_per_px)
    color = np.stack([0.2 * slope_x, 0.2 * slope_y, 0.1 * (slope_x + slope_y)], -1)
    noise = np.random.default_rng(seed).normal(0.0, 0.003, background.shape)
    return jnp.asarray(np.clip(background + color + noise, 0.0, 1.0), jnp.float32)


@pytest.fixture(scope="module")
def small_fast_model():
    """The ``fast`` preset, randomly initialised, on a 20 x 28 px sensor at 0.4 mm/px."""
    background = np.random.default_rng(0).uniform(0.3, 0.6, (20, 28, 3)).astype(np.float32)
    model = init_shape_model(jax.random.key(1), "fast", background, 0.4)
    # Random weights give a random slope field; scale the last layer so heights are ~0.1-1 mm.
    params = jax.tree.map(lambda p: p, model.params)  # a copy, edited below
    params["slope_net"]["Dense_3"]["kernel"] = params["slope_net"]["Dense_3"]["kernel"] * 0.3
    return model.replace(params=params)


# --- tests ---------------------------------------------------------------------------------------

def test_patches_match_conv_patches_exactly():
    x = jnp.asarray(np.random.default_rng(0).normal(size=(7, 9, 5)), jnp.float32)
    expected = reference_patches(x)
    np.testing.assert_array_equal(jax.jit(pixel_patches)(x), expected)
    np.testing.assert_array_equal(pixel_patches(x), expected)
    # Leading batch axes, and the channels-first planes are the same numbers transposed.
    batch = jnp.stack([x, 2 * x])
    np.testing.assert_array_equal(pixel_patches(batch)[1], reference_patches(2 * x))
    np.testing.assert_array_equal(jnp.moveaxis(patch_planes(jnp.moveaxis(x, -1, 0)), 0, -1), expected)


@pytest.mark.parametrize("preset", ["fast", "tiny"])
def test_same_parameters_and_initial_weights_as_before(preset):
    inputs = jnp.ones((6, 8, 5))
    new = build_network(preset, 0.2).init(jax.random.key(3), inputs)["params"]
    old = reference_network(preset, 0.2).init(jax.random.key(3), inputs)["params"]
    assert jax.tree.structure(new) == jax.tree.structure(old)
    jax.tree.map(np.testing.assert_array_equal, new, old)


def test_slopes_channels_first_equal_channels_last():
    network = build_network("fast", 0.2)
    params = network.init(jax.random.key(0), jnp.ones((6, 8, 5)))["params"]
    patches = jnp.asarray(np.random.default_rng(1).normal(size=(10, 45)), jnp.float32)
    last = network.apply({"params": params}, patches, method=SlopePoissonNet.slope)
    first = network.apply({"params": params}, patches.T, method=lambda net, x: net.slope_net(x, channels_first=True))
    np.testing.assert_allclose(first.T, last, atol=1e-5)
    expected = ReferenceSlopeNet(32, 2).apply({"params": params["slope_net"]}, patches)
    np.testing.assert_allclose(last, expected, atol=1e-6)


@pytest.mark.parametrize("seed", [0, 1])
def test_integration_matches_scipy_fft_dct(seed):
    slope = jnp.asarray(np.random.default_rng(seed).normal(size=(13, 17, 2)) * 0.2, jnp.float32)
    fast = jax.jit(integrate_gradient, static_argnums=1)(slope, 0.3)
    np.testing.assert_allclose(fast, jax.jit(reference_integrate, static_argnums=1)(slope, 0.3), atol=2e-6)


@pytest.mark.parametrize("shape", [(1,), (2,), (7,), (20, 28), (120, 160)])
def test_quantile_equals_jnp_quantile_exactly(shape):
    rng = np.random.default_rng(len(shape))
    values = jnp.asarray(rng.normal(size=shape) * 10.0 ** rng.uniform(-3, 3, shape), jnp.float32)
    for q in (0.0, 0.1, 0.37, 0.5, 1.0):
        assert jax.jit(quantile, static_argnums=1)(values.ravel(), q) == jnp.quantile(values, q)
    anchored = jax.jit(zero_background)(values.reshape(shape[0], -1))
    np.testing.assert_array_equal(anchored, values.reshape(shape[0], -1) - jnp.quantile(values, 0.1))


def test_order_statistics_with_ties_negative_zero_and_float64():
    values = jnp.asarray([3.0, -0.0, 0.0, -2.5, 3.0, 3.0, -1e-30, 1e30, -2.5], jnp.float32)
    np.testing.assert_array_equal(order_statistics(values, tuple(range(9))), jnp.sort(values))
    np.testing.assert_array_equal(order_statistics_by_bisection(values, tuple(range(9))), jnp.sort(values))
    with jax.enable_x64(True):
        wide = jnp.asarray(np.random.default_rng(2).normal(size=101) * 1e-9 + 1.0)
        assert wide.dtype == jnp.float64
        assert quantile(wide, 0.1) == jnp.quantile(wide, 0.1)


def test_both_order_statistics_pick_the_same_elements():
    """The bisection (a CPU's) and the sort (an accelerator's) return the same values, bit for bit."""
    rng = np.random.default_rng(5)
    values = jnp.asarray(rng.normal(size=19_200) * 10.0 ** rng.uniform(-3, 3, 19_200), jnp.float32)
    ranks = (0, 1_919, 1_920, 9_600, 19_199)
    by_bisection = jax.jit(order_statistics_by_bisection, static_argnums=1)(values, ranks)
    np.testing.assert_array_equal(by_bisection, jax.jit(order_statistics_by_sort, static_argnums=1)(values, ranks))
    np.testing.assert_array_equal(by_bisection, np.sort(np.asarray(values))[list(ranks)])
    # Ranks as data (e.g. a count of valid values): the same elements, one program for any ranks.
    traced = jnp.asarray(ranks, jnp.int32)
    np.testing.assert_array_equal(jax.jit(order_statistics_by_bisection)(values, traced), by_bisection)
    np.testing.assert_array_equal(jax.jit(order_statistics)(values, traced), by_bisection)


@pytest.mark.parametrize("method", ["as_this_device_runs_it", "by_bisection", "by_comparison", "by_sort"])
@pytest.mark.parametrize("size", [1, 7, 128, 256, 300])
def test_one_rank_as_data_is_the_sorts_element(size, method):
    """ICP's trimming threshold (one rank, traced, per iteration): every selection (a CPU's and an
    accelerator's) picks the sort's element, ties and inf included."""
    select = {"as_this_device_runs_it": order_statistics, "by_bisection": order_statistics_by_bisection,
              "by_comparison": order_statistics_by_comparison, "by_sort": order_statistics_by_sort}[method]

    def kth_smallest(values, k):
        return select(values, k[None])[0]

    rng = np.random.default_rng(size)
    values = rng.normal(size=(6, size)).astype(np.float32)
    values[1] = np.round(values[1], 1)  # ties
    values[2, rng.integers(0, size, size // 3 + 1)] = np.inf  # invalid matches, as robust_weights marks them
    values[3] = 0.0
    ks = jnp.asarray(rng.integers(0, size, 6), jnp.int32)
    expected = jnp.sort(jnp.asarray(values), axis=1)[jnp.arange(6), ks]
    np.testing.assert_array_equal(jax.jit(jax.vmap(kth_smallest))(values, ks), expected)
    for k in {0, size // 2, size - 1}:
        assert kth_smallest(jnp.asarray(values[0]), jnp.int32(k)) == jnp.sort(values[0])[k]


def test_quantile_gradient_matches_the_sort():
    values = jnp.asarray(np.random.default_rng(4).normal(size=50), jnp.float32)
    for q in (0.1, 0.5):
        np.testing.assert_allclose(jax.grad(lambda v: quantile(v, q))(values),
                                   jax.grad(lambda v: jnp.quantile(v, q))(values), atol=1e-6)


def test_predict_matches_the_replaced_formulation(small_fast_model):
    model = small_fast_model
    images = jnp.stack([_press(np.asarray(model.background), depth, model.mm_per_px, seed)
                        for seed, depth in enumerate([0.5, 1.2])])
    heightmaps, masks = predict_batch(model, images)
    for k in range(2):
        expected_height, expected_mask = jax.jit(reference_predict)(model, images[k])
        assert float(jnp.max(expected_height)) > 0.05  # a real contact, not all zeros
        np.testing.assert_allclose(heightmaps[k], expected_height, atol=1e-5)
        height, mask = predict(model, images[k])
        np.testing.assert_allclose(height, expected_height, atol=1e-5)
        # The mask may flip only where the height sits on the threshold, to round-off.
        threshold = float(model.params["mask_threshold_mm"])
        flipped = np.asarray(mask != expected_mask)
        assert np.all(np.abs(np.asarray(expected_height)[flipped] - threshold) < 1e-4)
        np.testing.assert_array_equal(masks[k], mask)


def test_bundled_model_matches_the_replaced_formulation():
    model = resolve_shape_model("bundled:fast-gelslim-0.5")
    spec = gelslim(scale=0.5)
    assert spec.shape == model.image_shape
    truth = _sphere_press(model.image_shape, 1.0, model.mm_per_px)
    image = add_sensor_noise(jax.random.key(0), spec, render_image(spec, jnp.asarray(truth, jnp.float32)))
    height, mask = predict(model, image)
    expected_height, expected_mask = jax.jit(reference_predict)(model, image)
    assert float(jnp.max(expected_height)) > 0.1
    np.testing.assert_allclose(height, expected_height, atol=1e-5)
    assert np.mean(np.asarray(mask) == np.asarray(expected_mask)) > 0.999


@pytest.mark.parametrize("preset", ["fast", "tiny"])
def test_coordinate_bias_is_the_first_layer_on_the_pixel_coordinates(preset):
    background = np.random.default_rng(2).uniform(0.3, 0.6, (9, 13, 3)).astype(np.float32)
    model = init_shape_model(jax.random.key(4), preset, background, 0.4)
    first = model.params["slope_net"]["Dense_0"]
    # Reference: the replaced patches of an input whose colour is zero, through nn.Dense.
    coordinates_only = reference_patches(network_input(background, background, preset)).reshape(-1, 45)
    expected = nn.Dense(first["bias"].shape[0]).apply({"params": first}, coordinates_only)
    np.testing.assert_allclose(coordinate_bias(model).T, expected, atol=1e-6)
    assert coordinate_bias(init_shape_model(jax.random.key(4), "paper", background, 0.4)) is None


def test_predict_with_coordinate_bias_matches_the_replaced_formulation(small_fast_model):
    model = small_fast_model
    bias = jax.jit(coordinate_bias)(model)
    images = jnp.stack([_press(np.asarray(model.background), depth, model.mm_per_px, seed)
                        for seed, depth in enumerate([0.5, 1.2])])
    heightmaps, masks = predict_batch(model, images, bias)
    for k in range(2):
        expected_height, expected_mask = jax.jit(reference_predict)(model, images[k])
        assert float(jnp.max(expected_height)) > 0.05
        np.testing.assert_allclose(heightmaps[k], expected_height, atol=1e-5)
        height, mask = predict(model, images[k], bias)
        np.testing.assert_allclose(height, expected_height, atol=1e-5)
        np.testing.assert_array_equal(mask, expected_mask)
        # Without jit: the module's own method.
        raw_height, _ = raw_prediction(model, images[k], coordinate_bias=bias)
        np.testing.assert_allclose(np.maximum(raw_height, 0.0), expected_height, atol=1e-5)
