"""Feature encoders for imprint retrieval (paper section VI, CTI): image -> unit feature vector.

An :class:`Encoder` is a pytree: the network's weights (``variables``) are its leaves, and the
architecture, input size and input normalisation are static fields, so one jitted function
serves every encoder of the same architecture and size. The input pipeline of one image is

    uint8 or [0, 1] image (H, W, 3) -> resize to ``input_size`` -> minus ``background``
    (if set) -> ``(x - mean) / std`` -> network -> pooled features (F,) -> L2-normalised,

so the cosine similarity of two imprints is the dot product of their features. ImageNet
encoders set ``mean``/``std`` to the ImageNet statistics and no background; the tactile encoder
(:mod:`tactojax.features._contrastive`) subtracts the sensor's no-contact frame, since the
colour change against it is what carries the contact shape.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray
from tqdm.auto import tqdm

from tactojax import _struct as struct
from tactojax.features._efficientnet import EfficientNetLite0
from tactojax.features._plain import PLAIN_PRESETS
from tactojax.features._resnet import RESNET_PRESETS

ARCHITECTURES: dict[str, Callable[[], nn.Module]] = {**RESNET_PRESETS, **PLAIN_PRESETS,
                                                     "efficientnet_lite0": EfficientNetLite0}
"""Architecture name -> module constructor, used to rebuild an encoder from a checkpoint.
Other encoder families register here (e.g. ``ARCHITECTURES.update(EFFICIENTNET_PRESETS)``)."""

TACTILE_MEAN = (0.0, 0.0, 0.0)
TACTILE_STD = (0.1, 0.1, 0.1)
"""Normalisation of the background-subtracted input: colour changes of a clear contact are
0.05-0.5, camera noise about 0.013 (in [0, 1] units)."""


@struct.dataclass
class Encoder:
    """A feature encoder: network weights plus the input pipeline (see the module docstring)."""

    variables: Any
    """Flax variables of ``module``: ``{"params": ..., "batch_stats": ...}``."""
    background: Float[Array, "h w 3"] | None
    """No-contact sensor frame at ``input_size``, RGB in [0, 1], subtracted from every
    resized image; None for encoders of raw images (ImageNet)."""
    module: nn.Module = struct.field(pytree_node=False)
    """The network; ``module.apply(variables, x)`` maps (N, h, w, 3) to (N, F) in eval mode."""
    architecture: str = struct.field(pytree_node=False)
    """Name of the architecture (a key of :data:`ARCHITECTURES` for checkpoints)."""
    input_size: tuple[int, int] = struct.field(pytree_node=False)
    """(h, w) pixels that images are resized to."""
    mean: tuple[float, float, float] = struct.field(pytree_node=False)
    std: tuple[float, float, float] = struct.field(pytree_node=False)
    """Per-channel normalisation ``(x - mean) / std`` after the background subtraction."""
    feature_dim: int = struct.field(pytree_node=False)
    """F, the length of a feature vector."""


def build_encoder(
    module: nn.Module,
    variables: Any,
    *,
    architecture: str,
    input_size: tuple[int, int],
    mean: tuple[float, float, float],
    std: tuple[float, float, float],
    background: Float[Array, "H W 3"] | None = None,
) -> Encoder:
    """Wrap a network and its weights (e.g. a loaded ImageNet model) as an :class:`Encoder`.

    Args:
        module: flax module mapping (N, h, w, 3) to pooled features (N, F) with its default
            (inference) arguments.
        variables: its variables (``params`` and, for BatchNorm, ``batch_stats``).
        architecture: name (to rebuild it from a checkpoint: a key of :data:`ARCHITECTURES`).
        input_size: (h, w) pixels the network sees.
        mean, std: per-channel input normalisation (images in [0, 1]).
        background: optional no-contact frame (any size, [0, 1]); resized to ``input_size``.

    Returns:
        The encoder; ``feature_dim`` is found by shape inference (nothing is computed).
    """
    height, width = (int(s) for s in input_size)
    probe = jax.ShapeDtypeStruct((1, height, width, 3), jnp.float32)
    shape = jax.eval_shape(lambda v, x: module.apply(v, x), variables, probe).shape
    if len(shape) != 2:
        raise ValueError(f"{architecture}: the module returns shape {shape}, not pooled (N, F) features")
    if background is not None:
        background = resize_image(jnp.asarray(background, jnp.float32), (height, width))
    return Encoder(variables=variables, background=background, module=module,
                   architecture=architecture, input_size=(height, width),
                   mean=tuple(float(m) for m in mean), std=tuple(float(s) for s in std),
                   feature_dim=int(shape[1]))


def init_encoder(
    key: PRNGKeyArray,
    preset: str,
    input_size: tuple[int, int],
    *,
    background: Float[Array, "H W 3"] | None = None,
    mean: tuple[float, float, float] = TACTILE_MEAN,
    std: tuple[float, float, float] = TACTILE_STD,
) -> Encoder:
    """A randomly initialised encoder of an architecture in :data:`ARCHITECTURES`.

    Args:
        key: PRNG key for the weights.
        preset: architecture name, e.g. ``"resnet_tactile"``.
        input_size: (h, w) pixels.
        background: optional no-contact frame (any size, RGB in [0, 1]).
        mean, std: input normalisation (default: for background-subtracted tactile images).
    """
    if preset not in ARCHITECTURES:
        raise ValueError(f"unknown encoder architecture {preset!r}; have {sorted(ARCHITECTURES)}")
    module = ARCHITECTURES[preset]()
    variables = jax.jit(module.init)(key, jnp.zeros((1, *input_size, 3), jnp.float32))  # eager init is slow
    return build_encoder(module, variables, architecture=preset, input_size=input_size,
                         mean=mean, std=std, background=background)


class PixelFeatures(nn.Module):
    """The flattened input image as its feature vector: the raw-pixel retrieval baseline."""

    @nn.compact
    def __call__(self, x: Float[Array, "N h w 3"], *, train: bool = False) -> Float[Array, "N F"]:
        return x.reshape(x.shape[0], -1)


ARCHITECTURES["pixels"] = PixelFeatures


def pixel_encoder(
    input_size: tuple[int, int],
    *,
    background: Float[Array, "H W 3"] | None = None,
) -> Encoder:
    """Raw pixels (downsampled to ``input_size``, minus ``background`` when given) as features:
    the baseline for retrieval with learned features."""
    return build_encoder(PixelFeatures(), {}, architecture="pixels", input_size=input_size,
                         mean=(0.0, 0.0, 0.0), std=(1.0, 1.0, 1.0), background=background)


def resize_image(image: Float[Array, "H W 3"], size: tuple[int, int]) -> Float[Array, "h w 3"]:
    """Bilinear resize (antialiased when shrinking) to ``size`` = (h, w); identity at that size."""
    if tuple(image.shape[:2]) == tuple(size):
        return image
    return jax.image.resize(image, (*size, image.shape[-1]), "linear", antialias=True)


def as_unit_range(images: Array) -> Float[Array, "..."]:
    """uint8 images to float32 in [0, 1]; float images are taken to be in [0, 1] already."""
    if images.dtype == jnp.uint8:
        return images.astype(jnp.float32) / 255.0
    return images.astype(jnp.float32)


def network_input(encoder: Encoder, image: Float[Array, "H W 3"]) -> Float[Array, "h w 3"]:
    """One image (uint8 or [0, 1]) -> the normalised (h, w, 3) network input."""
    x = resize_image(as_unit_range(image), encoder.input_size)
    if encoder.background is not None:
        x = x - encoder.background
    return (x - jnp.asarray(encoder.mean)) / jnp.asarray(encoder.std)


def normalize_features(features: Float[Array, "N F"]) -> Float[Array, "N F"]:
    """Rows scaled to unit L2 norm (an all-zero row stays zero)."""
    norm = jnp.linalg.norm(features, axis=-1, keepdims=True)
    return features / jnp.maximum(norm, 1e-12)


def apply_encoder(encoder: Encoder, images: Float[Array, "N H W 3"]) -> Float[Array, "N F"]:
    """Pure batched encoding: (N, H, W, 3) images -> (N, F) unit features (eval mode)."""
    x = jax.vmap(functools.partial(network_input, encoder))(images)
    features = encoder.module.apply(encoder.variables, x)
    return normalize_features(features.astype(jnp.float32))


_apply_jit = jax.jit(apply_encoder)


def encode_images(
    encoder: Encoder,
    images: Float[Array, "K H W 3"] | np.ndarray,
    *,
    batch_size: int = 64,
    progress: bool = False,
) -> Float[Array, "K F"]:
    """L2-normalised features of a stack of imprints, in fixed-size jitted batches.

    The last batch is padded to ``batch_size`` (the network is compiled once per image shape
    and batch size); the network runs in eval mode, so each feature depends on its own image
    only.

    Args:
        encoder: the encoder.
        images: (K, H, W, 3) uint8, or float in [0, 1]; any H, W (resized to the input size).
        batch_size: images per compiled call.
        progress: show a progress bar.

    Returns:
        (K, F) float32 unit vectors: the cosine similarity of imprints i, j is ``f_i @ f_j``.
    """
    if images.ndim != 4 or images.shape[-1] != 3:
        raise ValueError(f"images must be (K, H, W, 3), got shape {images.shape}")
    count = images.shape[0]
    if count == 0:
        return jnp.zeros((0, encoder.feature_dim), jnp.float32)
    batch_size = max(1, min(batch_size, count))
    parts = []
    bar = tqdm(total=count, desc="encode", unit="imprint", disable=not progress)
    for start in range(0, count, batch_size):
        batch = np.asarray(images[start:start + batch_size])
        real = batch.shape[0]
        if real < batch_size:  # pad with copies of the last image: one compiled shape
            batch = np.concatenate([batch, np.repeat(batch[-1:], batch_size - real, axis=0)])
        parts.append(_apply_jit(encoder, batch)[:real])
        bar.update(real)
    bar.close()
    return jnp.concatenate(parts)


def encode_image(encoder: Encoder, image: Float[Array, "H W 3"] | np.ndarray) -> Float[Array, "F"]:
    """The unit feature vector (F,) of one imprint (uint8 or [0, 1] RGB, (H, W, 3))."""
    return encode_images(encoder, np.asarray(image)[None], batch_size=1)[0]


def with_background(encoder: Encoder, background: Float[Array, "H W 3"] | np.ndarray | None) -> Encoder:
    """The encoder with another no-contact frame (uint8 or [0, 1], any size), or None for none.

    Use this when a tactile encoder trained on one sensor unit is used with another: capture
    a frame with nothing touching the gel and pass it here.
    """
    if background is None:
        return encoder.replace(background=None)
    frame = as_unit_range(jnp.asarray(background))
    return encoder.replace(background=resize_image(frame, encoder.input_size))
