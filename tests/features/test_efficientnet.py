"""EfficientNet-Lite's depthwise convolution against flax's grouped convolution, and the network built with it."""

import flax.linen as nn
import jax
import numpy as np
import pytest

from tactojax.features._efficientnet import DepthwiseConv


@pytest.mark.parametrize("kernel_size", [3, 5])
@pytest.mark.parametrize("strides", [1, 2])
@pytest.mark.parametrize("shape", [(2, 9, 12, 4), (1, 8, 7, 3)])  # odd and even sizes (SAME pads them differently)
def test_depthwise_conv_matches_a_grouped_convolution(kernel_size, strides, shape):
    x = np.random.default_rng(0).normal(size=shape).astype(np.float32)
    channels = shape[-1]
    reference = nn.Conv(channels, (kernel_size, kernel_size), strides, padding="SAME",
                        feature_group_count=channels, use_bias=False)
    variables = reference.init(jax.random.key(1), x)  # same parameter tree: {"params": {"kernel": (k, k, 1, C)}}
    expected = reference.apply(variables, x)
    ours = DepthwiseConv(kernel_size, strides)
    assert jax.tree.map(np.shape, ours.init(jax.random.key(1), x)) == jax.tree.map(np.shape, variables)
    np.testing.assert_allclose(ours.apply(variables, x), expected, rtol=1e-5, atol=1e-5)


def test_grouped_depthwise_network_has_the_same_parameters_and_output():
    """``grouped_depthwise=True`` (the ONNX-export graph) against the shifted products."""
    from tactojax.features import EfficientNetLiteTiny

    x = np.random.default_rng(0).normal(size=(2, 24, 32, 3)).astype(np.float32)
    shifted, grouped = EfficientNetLiteTiny(), EfficientNetLiteTiny(grouped_depthwise=True)
    variables = shifted.init(jax.random.key(0), x)
    assert jax.tree.map(np.shape, grouped.init(jax.random.key(0), x)) == jax.tree.map(np.shape, variables)
    np.testing.assert_allclose(grouped.apply(variables, x), shifted.apply(variables, x), rtol=1e-4, atol=1e-5)
