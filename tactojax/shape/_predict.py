"""ShapeModel and ``predict``: one tactile image -> contact heightmap and mask (paper section IV)."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from tactojax import _struct as struct
from tactojax.shape._lookup import lookup_slope
from tactojax.shape._models import (MASK_SHARPNESS_MM, USES_BACKGROUND, SlopePoissonNet, build_network,
                                    pixel_coordinates)
from tactojax.shape._poisson import integrate_gradient, zero_background

DEFAULT_COLOR_GAIN = 1.0
"""Scale of the colour change against the background fed to ``fast``/``tiny``. Measured on the
calibration shapes (2000 pairs, default training): gain 1 gives 0.030 mm contact-patch RMSE,
gain 8 (which brings the few-hundredths colour changes to unit scale) 0.036 mm. Each model
stores its own gain."""

LOOKUP = "lookup"
"""Preset name of the classical colour -> slope lookup model (no network)."""


@struct.dataclass
class ShapeModel:
    """A trained image -> heightmap model for one sensor: preset, weights and background frame.

    ``params`` holds the flax weights of a network preset, or for ``lookup``
    ``{"table": (B, B, B, 2), "color_range": (), "mask_threshold_mm": ()}``.
    """

    params: Any
    """Network weights (a pytree)."""
    background: Float[Array, "H W 3"]
    """The sensor's image with nothing touching, RGB in [0, 1]."""
    preset: str = struct.field(pytree_node=False)
    """``paper``, ``fast``, ``tiny`` or ``lookup``."""
    mm_per_px: float = struct.field(pytree_node=False)
    """Pixel pitch of the sensor the model was trained for, mm."""
    sensor: str = struct.field(pytree_node=False, default="")
    """Name of that sensor (preset name, or a user's label)."""
    color_gain: float = struct.field(pytree_node=False, default=DEFAULT_COLOR_GAIN)
    """Factor on the colour change against the background in the network input (presets
    that use the background only)."""

    @property
    def image_shape(self) -> tuple[int, int]:
        """(H, W) of the images the model takes."""
        return tuple(self.background.shape[:2])


def init_shape_model(
    key: PRNGKeyArray,
    preset: str,
    background: Float[Array, "H W 3"],
    mm_per_px: float,
    *,
    sensor: str = "",
    color_gain: float = DEFAULT_COLOR_GAIN,
) -> ShapeModel:
    """A network preset with freshly initialised weights (use ``train_shape_model`` to train)."""
    network = build_network(preset, mm_per_px)
    background = jnp.asarray(background, jnp.float32)
    dummy = network_input(background, background, preset, color_gain)
    params = jax.jit(network.init)(key, dummy)["params"]  # one compilation, not one per layer
    return ShapeModel(params=params, background=background, preset=preset, mm_per_px=mm_per_px,
                      sensor=sensor, color_gain=color_gain)


def network_input(
    image: Float[Array, "H W 3"],
    background: Float[Array, "H W 3"],
    preset: str,
    color_gain: float = DEFAULT_COLOR_GAIN,
) -> Float[Array, "H W 5"]:
    """The network's input: colour (raw, or ``color_gain`` times the change against the
    background) and the pixel's x, y in [-1, 1]."""
    height_px, width_px = image.shape[:2]
    if USES_BACKGROUND[preset]:
        color = color_gain * (image - background)
    else:
        color = image
    return jnp.concatenate([color, pixel_coordinates(height_px, width_px)], axis=-1).astype(jnp.float32)


def coordinate_bias(model: ShapeModel) -> Float[Array, "F N"] | None:
    """What a ``fast``/``tiny`` model's first slope layer adds at each pixel whatever the image:
    its bias and the pixel x/y inputs' part (:meth:`SlopePoissonNet.coordinate_bias`).

    Compute it once per model and pass it to :func:`predict` (as the live ``Localizer`` does):
    the first layer then multiplies 27 colour rows per pixel instead of 45 (issue 17). Pass it
    only with the weights it was computed from.

    Returns:
        (F, H*W), F the first layer's width; None for presets without a slope network.
    """
    network = build_network(model.preset, model.mm_per_px) if model.preset != LOOKUP else None
    if not isinstance(network, SlopePoissonNet):
        return None
    return network.apply({"params": model.params}, *model.image_shape, method=SlopePoissonNet.coordinate_bias)


def raw_prediction(
    model: ShapeModel, image: Float[Array, "H W 3"], background: Float[Array, "H W 3"] | None = None,
    *, coordinate_bias: Float[Array, "F N"] | None = None,
) -> tuple[Float[Array, "H W"], Float[Array, "H W"]]:
    """Unclipped heightmap (mm) and contact logit, as training sees them.

    ``background`` overrides the model's frame (e.g. one recaptured under new lighting);
    ``coordinate_bias`` is :func:`coordinate_bias` of this model (same output to round-off).
    """
    background = model.background if background is None else background
    if model.preset == LOOKUP:
        slope = lookup_slope(model.params["table"], model.params["color_range"], image - background)
        heightmap = zero_background(integrate_gradient(slope, model.mm_per_px))
        return heightmap, (heightmap - model.params["mask_threshold_mm"]) / MASK_SHARPNESS_MM
    network = build_network(model.preset, model.mm_per_px)
    if coordinate_bias is not None:
        color = model.color_gain * (image - background)
        output = network.apply({"params": model.params}, color, coordinate_bias, method=SlopePoissonNet.from_color)
    else:
        inputs = network_input(image, background, model.preset, model.color_gain)
        output = network.apply({"params": model.params}, inputs)
    return output[..., 0], output[..., 1]


@jax.jit
def predict(
    model: ShapeModel, image: Float[Array, "H W 3"], coordinate_bias: Float[Array, "F N"] | None = None
) -> tuple[Float[Array, "H W"], Bool[Array, "H W"]]:
    """Contact heightmap and mask from one tactile image (paper section IV).

    Compiles once per model preset and image size; vmap it (or use :func:`predict_batch`) for
    batches.

    Args:
        model: a trained :class:`ShapeModel` for this sensor.
        image: (H, W, 3) RGB in [0, 1], the model's image size.
        coordinate_bias: optional, :func:`coordinate_bias` of ``model``, computed once: the
            same result to float32 round-off, faster (issue 17).

    Returns:
        (heightmap (H, W) indentation depth in mm, >= 0; mask (H, W) contact).
    """
    heightmap, logit = raw_prediction(model, image, coordinate_bias=coordinate_bias)
    mask = logit > 0.0
    return jnp.maximum(heightmap, 0.0), mask


@jax.jit
def predict_batch(
    model: ShapeModel, images: Float[Array, "N H W 3"], coordinate_bias: Float[Array, "F P"] | None = None
) -> tuple[Float[Array, "N H W"], Bool[Array, "N H W"]]:
    """:func:`predict` over a leading batch axis."""
    return jax.vmap(predict, in_axes=(None, 0, None))(model, images, coordinate_bias)


def check_image(model: ShapeModel, image) -> None:
    """Raise a clear ``ValueError`` if ``image`` is not an (…, H, W, 3) image this model takes."""
    shape = tuple(getattr(image, "shape", ()))
    expected = (*model.image_shape, 3)
    if len(shape) < 3 or shape[-3:] != expected:
        raise ValueError(
            f"image shape {shape} does not match the shape model's (..., {expected[0]}, "
            f"{expected[1]}, 3) (sensor {model.sensor or 'unknown'}, {model.mm_per_px} mm/px)"
        )
