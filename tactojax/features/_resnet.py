"""ResNet feature encoders (He et al. 2016), torchvision-compatible layout. Architecture only.

The layers mirror torchvision's ``resnet18`` / ``resnet50`` exactly (explicit symmetric
padding, a 3x3 max-pool with -inf padding, the stride on the bottleneck's 3x3 convolution,
BatchNorm with eps 1e-5) so that ImageNet weights a user provides convert one to one
(:mod:`tactojax.features._convert`). Input: ``(N, H, W, 3)`` normalised images; output: the
globally average-pooled feature vector ``(N, C)``, or class logits when ``num_classes`` is set.

Presets are ``functools.partial`` of :class:`ResNet`: ``ResNet18``, ``ResNet50`` (the paper's
retrieval features, section VI), and the narrow ``ResNetTactile`` (a few MB) and ``ResNetTiny``
(for tests).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import flax.linen as nn
import jax.numpy as jnp
from jaxtyping import Array, Float

_PAD_3x3 = ((1, 1), (1, 1))


class BasicBlock(nn.Module):
    """Two 3x3 convolutions with a residual connection (ResNet18/34)."""

    filters: int
    strides: int = 1

    @nn.compact
    def __call__(self, x, *, train: bool = False):
        norm = functools.partial(nn.BatchNorm, use_running_average=not train, momentum=0.9, epsilon=1e-5)
        residual = x
        y = nn.Conv(self.filters, (3, 3), self.strides, padding=_PAD_3x3, use_bias=False, name="conv1")(x)
        y = nn.relu(norm(name="bn1")(y))
        y = nn.Conv(self.filters, (3, 3), padding=_PAD_3x3, use_bias=False, name="conv2")(y)
        y = norm(name="bn2")(y)
        if residual.shape != y.shape:
            residual = nn.Conv(self.filters, (1, 1), self.strides, use_bias=False, name="downsample_conv")(x)
            residual = norm(name="downsample_bn")(residual)
        return nn.relu(y + residual)


class Bottleneck(nn.Module):
    """1x1 -> 3x3 (strided) -> 1x1 x4 convolutions with a residual connection (ResNet50, v1.5)."""

    filters: int
    strides: int = 1

    @nn.compact
    def __call__(self, x, *, train: bool = False):
        norm = functools.partial(nn.BatchNorm, use_running_average=not train, momentum=0.9, epsilon=1e-5)
        residual = x
        y = nn.Conv(self.filters, (1, 1), use_bias=False, name="conv1")(x)
        y = nn.relu(norm(name="bn1")(y))
        y = nn.Conv(self.filters, (3, 3), self.strides, padding=_PAD_3x3, use_bias=False, name="conv2")(y)
        y = nn.relu(norm(name="bn2")(y))
        y = nn.Conv(self.filters * 4, (1, 1), use_bias=False, name="conv3")(y)
        y = norm(name="bn3")(y)
        if residual.shape != y.shape:
            residual = nn.Conv(self.filters * 4, (1, 1), self.strides, use_bias=False, name="downsample_conv")(x)
            residual = norm(name="downsample_bn")(residual)
        return nn.relu(y + residual)


class ResNet(nn.Module):
    """ResNet trunk with global average pooling.

    Attributes:
        stage_sizes: blocks per stage (e.g. (2, 2, 2, 2) for ResNet18).
        block: :class:`BasicBlock` or :class:`Bottleneck`.
        width: filters of the stem and the first stage (64 in torchvision); each stage doubles it.
        num_classes: if set, a final dense layer returns logits instead of pooled features.
    """

    stage_sizes: Sequence[int]
    block: type[nn.Module] = BasicBlock
    width: int = 64
    num_classes: int | None = None

    @nn.compact
    def __call__(self, x: Float[Array, "N H W 3"], *, train: bool = False) -> Float[Array, "N C"]:
        x = nn.Conv(self.width, (7, 7), (2, 2), padding=((3, 3), (3, 3)), use_bias=False, name="conv1")(x)
        x = nn.BatchNorm(use_running_average=not train, momentum=0.9, epsilon=1e-5, name="bn1")(x)
        x = nn.relu(x)
        x = nn.max_pool(x, (3, 3), (2, 2), padding=_PAD_3x3)
        for stage, blocks in enumerate(self.stage_sizes):
            for index in range(blocks):
                strides = 2 if stage > 0 and index == 0 else 1
                x = self.block(self.width * 2**stage, strides, name=f"layer{stage + 1}_{index}")(x, train=train)
        features = jnp.mean(x, axis=(1, 2))
        if self.num_classes is None:
            return features
        return nn.Dense(self.num_classes, name="fc")(features)


ResNet18 = functools.partial(ResNet, stage_sizes=(2, 2, 2, 2), block=BasicBlock)
ResNet50 = functools.partial(ResNet, stage_sizes=(3, 4, 6, 3), block=Bottleneck)
ResNetTactile = functools.partial(ResNet, stage_sizes=(2, 2, 2, 2), block=BasicBlock, width=16)
"""ResNet18 at a quarter of the width: 0.7 M parameters (2.8 MB), for the tactile-trained encoder."""
ResNetTiny = functools.partial(ResNet, stage_sizes=(1, 1), block=BasicBlock, width=8)
"""Two stages of width 8: for tests."""

RESNET_PRESETS = {"resnet18": ResNet18, "resnet50": ResNet50, "resnet_tactile": ResNetTactile, "resnet_tiny": ResNetTiny}
