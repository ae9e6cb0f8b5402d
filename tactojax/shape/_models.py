"""Network architectures: tactile image -> (heightmap, contact logit). Architecture only.

Every model takes one normalised input, ``(H, W, C)`` with the pixel's x and y coordinates
in [-1, 1] as the last two channels (paper section IV), and returns ``(H, W, 2)``: heightmap in
mm and the contact-mask logit. Presets are ``functools.partial`` of the two families:

* ``paper``: the paper's CNN, 10 conv layers x 64 filters x 3x3 on the raw image.
* ``fast``: a per-pixel MLP on each pixel's 3x3 neighbourhood that predicts the surface
  slope from the colour change against the background frame and the pixel position, followed
  by a differentiable Poisson integration (:mod:`tactojax.shape._poisson`); contact where the
  height exceeds a threshold. 84x fewer multiply-adds per pixel than ``paper``
  (``flops_per_pixel``).
* ``tiny``: ``fast`` with 8 features, for tests.
"""

from __future__ import annotations

import functools
from typing import Callable

import flax.linen as nn
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, Float

from tactojax.shape._poisson import integrate_gradient, zero_background


class ConvHeightNet(nn.Module):
    """A plain stack of same-padded 3x3 convolutions with ReLU (paper section IV)."""

    features: int = 64
    layers: int = 10

    @nn.compact
    def __call__(self, x: Float[Array, "H W C"]) -> Float[Array, "H W 2"]:
        for _ in range(self.layers - 1):
            x = nn.relu(nn.Conv(self.features, (3, 3))(x))
        return nn.Conv(2, (3, 3))(x)


def pixel_patches(x: Float[Array, "... H W C"]) -> Float[Array, "... H W 9C"]:
    """Every pixel's 3x3 neighbourhood (zero-padded) flattened into its channels.

    Feature ``9c + 3i + j`` is channel ``c`` at row offset ``i - 1`` and column offset
    ``j - 1``, the layout of ``jax.lax.conv_general_dilated_patches`` (which the slope weights
    were trained with).
    """
    planes = jnp.moveaxis(x, -1, -3)
    return jnp.moveaxis(patch_planes(planes), -3, -1)


def patch_planes(planes: Float[Array, "... C H W"]) -> Float[Array, "... 9C H W"]:
    """:func:`pixel_patches` with the channels first: ``9C`` planes of shifted copies.

    Built from three column shifts, then three row shifts of those: XLA fuses each three-way
    stack into one kernel (a nine-way one is nine kernels, and the patch extraction as a
    convolution with an identity kernel does 45 multiply-adds per output; issue 17).
    """
    height_px, width_px = planes.shape[-2:]
    padding = [(0, 0)] * (planes.ndim - 2) + [(1, 1), (1, 1)]
    padded = jnp.pad(planes, padding)
    columns = jnp.stack([padded[..., :, j:j + width_px] for j in range(3)], axis=-3)  # C 3 H+2 W
    patches = jnp.stack([columns[..., i:i + height_px, :] for i in range(3)], axis=-4)  # C 3 3 H W
    return patches.reshape((*planes.shape[:-3], -1, height_px, width_px))


class PixelDense(nn.Module):
    """A dense layer on each pixel's features, the pixels stored channels last or first.

    Its parameters are ``nn.Dense``'s (``kernel`` (in, out), ``bias`` (out,), same
    initialisers), so checkpoints and initial weights are unchanged.
    """

    features: int

    @nn.compact
    def __call__(self, x: Float[Array, "..."], *, channels_first: bool = False) -> Float[Array, "..."]:
        """(..., in) -> (..., out), or with ``channels_first`` (in, N) -> (out, N)."""
        in_features = x.shape[0] if channels_first else x.shape[-1]
        kernel = self.param("kernel", nn.initializers.lecun_normal(), (in_features, self.features))
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))
        if not channels_first:
            return jnp.dot(x, kernel) + bias
        # The barrier keeps kernel^T a (tiny) array of its own: XLA would fold the transpose into
        # the product, which its CPU runtime then runs as a generic dot instead of handing it to
        # its matrix library, 20-25 % slower for the MLP of ``fast`` (issue 17).
        return lax.optimization_barrier(kernel.T) @ x + bias[:, None]


class SlopeNet(nn.Module):
    """Per-pixel MLP: a pixel's 3x3 input neighbourhood -> surface slope (dh/dx, dh/dy)."""

    features: int = 32
    hidden_layers: int = 2

    @nn.compact
    def __call__(self, patches: Float[Array, "..."], *, channels_first: bool = False) -> Float[Array, "..."]:
        """(..., 9C) patches -> (..., 2) slopes, or with ``channels_first`` (9C, N) -> (2, N)."""
        widths = [self.features] * (self.hidden_layers + 1) + [2]
        hidden = patches
        for index, width in enumerate(widths):
            hidden = PixelDense(width, name=f"Dense_{index}")(hidden, channels_first=channels_first)
            if index < len(widths) - 1:
                hidden = nn.relu(hidden)
        return hidden


class SlopePoissonNet(nn.Module):
    """Per-pixel slope regression, then Poisson integration; contact where the height exceeds
    a learned threshold (as in the classical method).

    The slope network sees each pixel independently, so it can be trained on sampled pixels
    against the true slope (:meth:`slope`), then end to end through the integration.
    """

    features: int = 32
    hidden_layers: int = 2
    mm_per_px: float = 0.1
    background_quantile: float = 0.1

    def setup(self):
        self.slope_net = SlopeNet(self.features, self.hidden_layers)
        self.mask_threshold_mm = self.param("mask_threshold_mm", nn.initializers.constant(0.1), ())

    def __call__(self, x: Float[Array, "H W C"]) -> Float[Array, "H W 2"]:
        height_px, width_px = x.shape[:2]
        # Channels first, pixels along the minor axis: the layout in which the CPU multiplies
        # all pixels by each layer fastest (issue 17).
        patches = patch_planes(jnp.moveaxis(x, -1, 0)).reshape(-1, height_px * width_px)
        slope = self.slope_net(patches, channels_first=True).reshape(2, height_px, width_px)
        heightmap = zero_background(
            integrate_gradient(jnp.moveaxis(slope, 0, -1), self.mm_per_px), quantile=self.background_quantile
        )
        mask_logit = (heightmap - self.mask_threshold_mm) / MASK_SHARPNESS_MM
        return jnp.stack([heightmap, mask_logit], axis=-1)

    def slope(self, patches: Float[Array, "... 9C"]) -> Float[Array, "... 2"]:
        """The slope of pixels given their 3x3 neighbourhoods (see :func:`pixel_patches`)."""
        return self.slope_net(patches)


MASK_SHARPNESS_MM = 0.01
"""Heights this far above the contact threshold give a contact logit of 1."""


PRESETS: dict[str, Callable[..., nn.Module]] = {
    "paper": functools.partial(ConvHeightNet, features=64, layers=10),
    "fast": functools.partial(SlopePoissonNet, features=32, hidden_layers=2),
    "tiny": functools.partial(SlopePoissonNet, features=8, hidden_layers=1),
}
"""Preset name -> flax module constructor."""

USES_BACKGROUND: dict[str, bool] = {"paper": False, "fast": True, "tiny": True}
"""Whether a preset sees the colour change against the background frame (else the raw image)."""


def build_network(preset: str, mm_per_px: float) -> nn.Module:
    """The flax module of a preset for a sensor with the given pixel pitch."""
    if preset not in PRESETS:
        raise ValueError(f"unknown shape-model preset {preset!r}; choose from {sorted(PRESETS)}")
    constructor = PRESETS[preset]
    if issubclass(constructor.func, SlopePoissonNet):
        return constructor(mm_per_px=mm_per_px)
    return constructor()


def flops_per_pixel(module: nn.Module, input_channels: int = 5) -> int:
    """Multiply-adds per pixel of the convolutions (the FFTs of the Poisson step excluded)."""
    if isinstance(module, ConvHeightNet):
        f = module.features
        return 9 * (input_channels * f + (module.layers - 2) * f * f + f * 2)
    if isinstance(module, SlopePoissonNet):
        f = module.features
        return 9 * input_channels * f + module.hidden_layers * f * f + f * 2
    raise TypeError(f"unknown module {type(module).__name__}")

