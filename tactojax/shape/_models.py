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
    def __call__(self, x: Float[Array, "..."], *, channels_first: bool = False,
                 pixel_bias: Float[Array, "out N"] | None = None,
                 in_features: int | None = None) -> Float[Array, "..."]:
        """(..., in) -> (..., out), or with ``channels_first`` (in, N) -> (out, N).

        With ``pixel_bias`` (channels first only): ``x`` holds the first ``x.shape[0]`` of the
        layer's ``in_features`` inputs, and ``pixel_bias`` (out, N) stands for the bias plus the
        other inputs' contribution at each pixel (see :meth:`SlopePoissonNet.coordinate_bias`).
        """
        in_features = in_features or (x.shape[0] if channels_first else x.shape[-1])
        kernel = self.param("kernel", nn.initializers.lecun_normal(), (in_features, self.features))
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))
        if not channels_first:
            return jnp.dot(x, kernel) + bias
        # The barrier keeps kernel^T a (tiny) array of its own: XLA would fold the transpose into
        # the product, which its CPU runtime then runs as a generic dot instead of handing it to
        # its matrix library, 20-25 % slower for the MLP of ``fast`` (issue 17).
        if pixel_bias is not None:
            return lax.optimization_barrier(kernel[:x.shape[0]].T) @ x + pixel_bias
        return lax.optimization_barrier(kernel.T) @ x + bias[:, None]


class SlopeNet(nn.Module):
    """Per-pixel MLP: a pixel's 3x3 input neighbourhood -> surface slope (dh/dx, dh/dy)."""

    features: int = 32
    hidden_layers: int = 2

    @nn.compact
    def __call__(self, patches: Float[Array, "..."], *, channels_first: bool = False,
                 coordinate_bias: Float[Array, "F N"] | None = None) -> Float[Array, "..."]:
        """(..., 9C) patches -> (..., 2) slopes, or with ``channels_first`` (9C, N) -> (2, N).

        With ``coordinate_bias`` (channels first): ``patches`` (9(C-2), N) hold only the colour
        channels' rows, and ``coordinate_bias`` (:meth:`SlopePoissonNet.coordinate_bias`) the
        first layer's bias plus what the pixel x/y channels add, the same at every call (issue 17).
        """
        widths = [self.features] * (self.hidden_layers + 1) + [2]
        hidden = patches
        for index, width in enumerate(widths):
            if index == 0 and coordinate_bias is not None:
                hidden = PixelDense(width, name="Dense_0")(
                    hidden, channels_first=True, pixel_bias=coordinate_bias,
                    in_features=patches.shape[0] + COORDINATE_PATCH_ROWS)
            else:
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
        return self._heights(self.slope_net(patches, channels_first=True).reshape(2, height_px, width_px))

    def from_color(self, color: Float[Array, "H W C2"],
                   coordinate_bias: Float[Array, "F N"]) -> Float[Array, "H W 2"]:
        """:meth:`__call__` of the input whose colour channels are ``color`` (the pixel x/y
        channels left out: ``coordinate_bias`` of these weights holds their part, see
        :meth:`coordinate_bias`); the same output to float32 round-off, with 40 % fewer rows
        in the first layer's product (issue 17)."""
        height_px, width_px = color.shape[:2]
        patches = patch_planes(jnp.moveaxis(color, -1, 0)).reshape(-1, height_px * width_px)
        slope = self.slope_net(patches, channels_first=True, coordinate_bias=coordinate_bias)
        return self._heights(slope.reshape(2, height_px, width_px))

    def _heights(self, slope: Float[Array, "2 H W"]) -> Float[Array, "H W 2"]:
        """Slope planes -> (heightmap, contact logit): integration, background, threshold."""
        heightmap = zero_background(
            integrate_gradient(jnp.moveaxis(slope, 0, -1), self.mm_per_px), quantile=self.background_quantile
        )
        mask_logit = (heightmap - self.mask_threshold_mm) / MASK_SHARPNESS_MM
        return jnp.stack([heightmap, mask_logit], axis=-1)

    def coordinate_bias(self, height_px: int, width_px: int) -> Float[Array, "F N"]:
        """The first slope layer's bias plus what the pixel x/y inputs add, per pixel: (F, H*W),
        F the layer's width, pixels in row-major order.

        The x/y channels are the same at every call, so their part of the first layer (18 of
        its 9C inputs) is a constant plane of the weights alone: computed once per model
        (:func:`tactojax.shape.coordinate_bias`), it leaves only the colour rows to multiply
        per image (:meth:`from_color`).
        """
        coordinates = jnp.moveaxis(pixel_coordinates(height_px, width_px), -1, 0)
        patches = patch_planes(coordinates).reshape(COORDINATE_PATCH_ROWS, height_px * width_px)
        first = self.slope_net.variables["params"]["Dense_0"]
        return first["kernel"][-COORDINATE_PATCH_ROWS:].T @ patches + first["bias"][:, None]

    def slope(self, patches: Float[Array, "... 9C"]) -> Float[Array, "... 2"]:
        """The slope of pixels given their 3x3 neighbourhoods (see :func:`pixel_patches`)."""
        return self.slope_net(patches)


COORDINATE_PATCH_ROWS = 18
"""Rows of the 3x3 patches that come from the pixel x/y channels (the last two of the input)."""


def pixel_coordinates(height_px: int, width_px: int) -> Float[Array, "H W 2"]:
    """Every pixel's x (along columns) and y (along rows) in [-1, 1]: the last two input
    channels of every model (paper section IV)."""
    rows = jnp.linspace(-1.0, 1.0, height_px)
    cols = jnp.linspace(-1.0, 1.0, width_px)
    y, x = jnp.meshgrid(rows, cols, indexing="ij")
    return jnp.stack([x, y], axis=-1).astype(jnp.float32)


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

