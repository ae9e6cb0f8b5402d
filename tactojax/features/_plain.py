"""A plain convolutional encoder for fast retrieval features on a CPU. Architecture only.

XLA's CPU backend runs a dense convolution or a matrix product as one library call, while a
depthwise or grouped convolution (EfficientNet's) becomes slow loops or many small kernels. So
this network uses only dense layers, at the sensor's native resolution (no upsampling):

    image (H, W, 3) -> space-to-depth by ``patch`` (H/p, W/p, 3 p^2) -> 1x1 convolution
    (a patch embedding, one matrix product) -> 3x3 convolutions (stride 1 or 2) ->
    global average pooling -> linear embedding (F,)

every convolution followed by BatchNorm and ReLU (one fused elementwise kernel after each
library call). A forward pass of the ``PlainTactile`` preset on one 120 x 160 image is about 70
MFLOPs in 15 kernels; EfficientNet-Lite0 at 168 x 224 is about 300 MFLOPs in 150.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import flax.linen as nn
import jax.numpy as jnp
from jaxtyping import Array, Float


def space_to_depth(x: Float[Array, "N H W C"], patch: int) -> Float[Array, "N h w D"]:
    """Non-overlapping ``patch`` x ``patch`` blocks as channels: (N, H, W, C) -> (N, H/p, W/p, p*p*C).

    The channel order within a block is (row, column, channel). H and W must be multiples of p.
    """
    count, height, width, channels = x.shape
    if height % patch or width % patch:
        raise ValueError(f"image {height} x {width} is not a multiple of the patch size {patch}")
    x = x.reshape(count, height // patch, patch, width // patch, patch, channels)
    return x.transpose(0, 1, 3, 2, 4, 5).reshape(count, height // patch, width // patch, patch * patch * channels)


class PlainConvNet(nn.Module):
    """Space-to-depth stem, dense 3x3 convolutions, global average pooling, linear embedding.

    Attributes:
        patch: side of the space-to-depth blocks (the stem's stride).
        stem_filters: channels of the patch embedding (a 1x1 convolution on the blocks).
        stages: (filters, stride) of each 3x3 convolution after the stem.
        features: F, the length of the output embedding.
    """

    patch: int = 4
    stem_filters: int = 32
    stages: Sequence[tuple[int, int]] = ((32, 1), (64, 2), (64, 1), (128, 2))
    features: int = 128

    @nn.compact
    def __call__(self, x: Float[Array, "N H W 3"], *, train: bool = False) -> Float[Array, "N F"]:
        norm = functools.partial(nn.BatchNorm, use_running_average=not train, momentum=0.9, epsilon=1e-5)
        x = space_to_depth(x, self.patch)
        x = nn.Dense(self.stem_filters, use_bias=False, name="stem")(x)
        x = nn.relu(norm(name="stem_bn")(x))
        for index, (filters, strides) in enumerate(self.stages):
            x = nn.Conv(filters, (3, 3), strides, padding="SAME", use_bias=False, name=f"conv{index}")(x)
            x = nn.relu(norm(name=f"bn{index}")(x))
        x = jnp.mean(x, axis=(1, 2))
        return nn.Dense(self.features, name="embedding")(x)


PlainTactile = functools.partial(PlainConvNet)
"""The shipped tactile encoder's network (``plain_tactile``): 4 x 4 patches to 32 channels,
3x3 convolutions of 32, 64 (stride 2), 64, 128 (stride 2) filters, 128 features."""
PlainTiny = functools.partial(PlainConvNet, patch=2, stem_filters=4, stages=((8, 2),), features=8)
"""One 3x3 convolution of 8 filters, 8 features: for tests."""

PLAIN_PRESETS = {"plain_tactile": PlainTactile, "plain_tiny": PlainTiny}
