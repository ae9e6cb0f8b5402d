"""Training the image -> heightmap networks with optax (paper section IV).

Seeded and deterministic: the batch at step ``s`` and its colour augmentation depend only on
``(seed, s)``, so a run resumed from a :class:`TrainState` continues exactly as if it had not
stopped. The loss is the heightmap MSE over the image plus over the contact patch (errors in
units of 0.1 mm), and a binary cross-entropy on the contact logit.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, Float, PRNGKeyArray
from tqdm.auto import tqdm

from tactojax import _struct as struct
from tactojax.geometry import heightmap_gradient
from tactojax.sensor import augment_colors
from tactojax.shape._data import ShapeData, estimate_background
from tactojax.shape._lookup import fit_mask_threshold
from tactojax.shape._models import USES_BACKGROUND, SlopePoissonNet, build_network, pixel_patches
from tactojax.shape._predict import (
    DEFAULT_COLOR_GAIN,
    ShapeModel,
    init_shape_model,
    network_input,
    raw_prediction,
)

HEIGHT_UNIT_MM = 0.1
"""Heightmap errors are measured in this unit inside the loss, to balance it with the BCE."""


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings (defaults: ``fast`` in a few minutes on 2 CPU cores)."""

    steps: int = 500
    """Steps on whole images, end to end (for ``paper``: all the training)."""
    pixel_steps: int = 2000
    """Steps before those that train only the slope network of ``fast``/``tiny`` on sampled
    pixels against the true slope (ignored for ``paper``)."""
    pixels_per_image: int = 2048
    crop_px: int = 0
    """``paper`` only: train on random crops of this size instead of whole images (0: off)."""
    batch_size: int = 8
    learning_rate: float = 3e-3
    fine_tune_learning_rate: float = 3e-4
    """Peak rate of the whole-image phase after a pixel phase."""
    warmup_steps: int = 100
    patch_weight: float = 1.0
    mask_weight: float = 0.1
    augment: bool = True
    seed: int = 0
    checkpoint_every: int = 250
    color_gain: float = DEFAULT_COLOR_GAIN
    """Factor on the colour change in the network input (``fast``/``tiny``; stored in the model)."""

    def total_steps(self, preset: str) -> int:
        """Pixel steps (slope networks only) plus whole-image steps."""
        return self.steps + (self.pixel_steps if has_slope_net(preset) else 0)


@struct.dataclass
class TrainState:
    """Everything needed to resume: the model, the optimiser state, the step and the history."""

    model: ShapeModel
    opt_state: Any
    step: int
    history: Float[Array, "S 2"]
    """(steps, 2) per step: the batch's loss, and its slope RMSE (pixel phase) or contact-patch
    RMSE in mm (whole-image phase)."""


def has_slope_net(preset: str) -> bool:
    """Whether a preset predicts per-pixel slopes (and so has a pixel training phase)."""
    return USES_BACKGROUND.get(preset, False)


def make_optimizer(config: TrainConfig, preset: str, *, pixels: bool = False) -> optax.GradientTransformation:
    """Adam with linear warm-up and cosine decay to 1 % of the peak rate, over one phase.

    The pixel phase and the whole-image phase each get a fresh optimiser: their losses differ
    in scale by orders of magnitude, and Adam's running second moments from one would make the
    first steps of the other far too large. The whole-image phase fine-tunes at
    ``config.fine_tune_learning_rate`` when a pixel phase came before it.
    """
    if pixels:
        total, peak = config.pixel_steps, config.learning_rate
    else:
        total = config.steps
        peak = config.fine_tune_learning_rate if has_slope_net(preset) and config.pixel_steps else config.learning_rate
    warmup = min(config.warmup_steps, max(total // 4, 1))
    schedule = optax.warmup_cosine_decay_schedule(
        0.0, peak, warmup, max(total, warmup + 1), end_value=0.01 * peak)
    return optax.chain(optax.clip_by_global_norm(1.0), optax.adam(schedule))


def init_train_state(
    preset: str, data: ShapeData, config: TrainConfig, *, background: np.ndarray | None = None
) -> TrainState:
    """A fresh state: initialised network, background frame estimated from ``data``."""
    if background is None:
        background = estimate_background(data)
    model = init_shape_model(jax.random.key(config.seed), preset, background, data.mm_per_px,
                             sensor=data.sensor, color_gain=config.color_gain)
    pixels = config.total_steps(preset) > config.steps
    opt_state = make_optimizer(config, preset, pixels=pixels).init(model.params)
    return TrainState(model=model, opt_state=opt_state, step=0,
                      history=jnp.zeros((config.total_steps(preset), 2), jnp.float32))


def _augmented(model: ShapeModel, key, image, config: TrainConfig):
    """(image, background) under one random lighting change, applied to both (the frame is
    recaptured under the new lighting)."""
    background = model.background
    if config.augment:
        image = augment_colors(key, image)
        if USES_BACKGROUND[model.preset]:
            background = augment_colors(key, background)
    return image, background


def pixel_loss(
    model: ShapeModel,
    key: PRNGKeyArray,
    image: Float[Array, "H W 3"],
    heightmap: Float[Array, "H W"],
    mask: Float[Array, "H W"],
    config: TrainConfig,
) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """(slope MSE, slope RMSE) at pixels sampled half from the contact patch, half anywhere."""
    augment_key, sample_key = jax.random.split(key)
    image, background = _augmented(model, augment_key, image, config)
    inputs = network_input(image, background, model.preset, model.color_gain)
    patches = pixel_patches(inputs).reshape(-1, 45)
    weights = 0.5 * mask.reshape(-1) / jnp.maximum(jnp.sum(mask), 1.0) + 0.5 / mask.size
    rows = jax.random.choice(sample_key, mask.size, (config.pixels_per_image,), p=weights)
    true_slope = heightmap_gradient(heightmap, model.mm_per_px).reshape(-1, 2)[rows]
    network = build_network(model.preset, model.mm_per_px)
    slope = network.apply({"params": model.params}, patches[rows], method=SlopePoissonNet.slope)
    mse = jnp.mean((slope - true_slope) ** 2)
    return mse, jnp.sqrt(mse)


def pair_loss(
    model: ShapeModel,
    key: PRNGKeyArray,
    image: Float[Array, "H W 3"],
    heightmap: Float[Array, "H W"],
    mask: Float[Array, "H W"],
    config: TrainConfig,
) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """(loss, contact-patch RMSE in mm) of one augmented training pair.

    Slope networks see the whole image (the Poisson step is global). The convolutional
    ``paper`` network, with ``config.crop_px``, sees a random crop centred on a contact pixel
    half of the time (its coordinate channels keep the crop's place in the image), and the loss
    skips a border as wide as its receptive field; this makes CPU training affordable.
    """
    augment_key, crop_key = jax.random.split(key)
    image, background = _augmented(model, augment_key, image, config)
    if config.crop_px and not has_slope_net(model.preset):
        network = build_network(model.preset, model.mm_per_px)
        inputs = network_input(image, background, model.preset, model.color_gain)
        inputs, heightmap, mask = _random_crop(crop_key, config.crop_px, inputs, heightmap, mask)
        output = network.apply({"params": model.params}, inputs)
        margin = getattr(network, "layers", 0)
        inner = (slice(margin, config.crop_px - margin),) * 2
        predicted, logit, heightmap, mask = output[..., 0][inner], output[..., 1][inner], heightmap[inner], mask[inner]
    else:
        predicted, logit = raw_prediction(model, image, background)
    error = (predicted - heightmap) / HEIGHT_UNIT_MM
    patch_pixels = jnp.maximum(jnp.sum(mask), 1.0)
    patch_mse = jnp.sum(mask * error**2) / patch_pixels
    bce = jnp.mean(optax.sigmoid_binary_cross_entropy(logit, mask))
    loss = jnp.mean(error**2) + config.patch_weight * patch_mse + config.mask_weight * bce
    return loss, jnp.sqrt(patch_mse) * HEIGHT_UNIT_MM


def _random_crop(key, size, inputs, heightmap, mask):
    """The same ``size`` x ``size`` crop of the input, heightmap and mask; centred on a random
    contact pixel half of the time, anywhere otherwise."""
    height, width = heightmap.shape
    pick_key, coin_key = jax.random.split(key)
    weights = jnp.where(jax.random.bernoulli(coin_key), mask.reshape(-1) + 1e-6, jnp.ones(mask.size))
    centre = jax.random.choice(pick_key, mask.size, p=weights / jnp.sum(weights))
    row = jnp.clip(centre // width - size // 2, 0, height - size)
    col = jnp.clip(centre % width - size // 2, 0, width - size)
    crop = lambda array: jax.lax.dynamic_slice(  # noqa: E731
        array, (row, col) + (0,) * (array.ndim - 2), (size, size) + array.shape[2:])
    return crop(inputs), crop(heightmap), crop(mask)


def make_train_step(config: TrainConfig, preset: str, *, pixels: bool = False) -> Callable:
    """A jitted pure ``train_step(state, key, images, heightmaps, masks) -> state``.

    ``pixels`` selects the slope-only phase (:func:`pixel_loss`) instead of :func:`pair_loss`.
    """
    optimizer = make_optimizer(config, preset, pixels=pixels)
    loss_fn = pixel_loss if pixels else pair_loss

    def batch_loss(params, model, key, images, heightmaps, masks):
        model = model.replace(params=params)
        keys = jax.random.split(key, images.shape[0])
        losses, metric = jax.vmap(loss_fn, in_axes=(None, 0, 0, 0, 0, None))(
            model, keys, images, heightmaps, masks, config)
        return jnp.mean(losses), jnp.mean(metric)

    @jax.jit
    def train_step(state: TrainState, key, images, heightmaps, masks) -> TrainState:
        (loss, patch_rmse), grads = jax.value_and_grad(batch_loss, has_aux=True)(
            state.model.params, state.model, key, images, heightmaps, masks)
        updates, opt_state = optimizer.update(grads, state.opt_state, state.model.params)
        params = optax.apply_updates(state.model.params, updates)
        history = state.history.at[state.step].set(jnp.stack([loss, patch_rmse]))
        return TrainState(model=state.model.replace(params=params), opt_state=opt_state,
                          step=state.step + 1, history=history)

    return train_step


def batch_indices(num_pairs: int, batch_size: int, seed: int, step: int) -> np.ndarray:
    """The pairs of training step ``step``: epochs of seeded random permutations."""
    per_epoch = max(1, num_pairs // batch_size)
    epoch, position = divmod(step, per_epoch)
    order = np.random.default_rng([seed, epoch]).permutation(num_pairs)
    return np.sort(order[position * batch_size:(position + 1) * batch_size])


def train_shape_model(
    preset: str,
    data: ShapeData,
    config: TrainConfig = TrainConfig(),
    *,
    state: TrainState | None = None,
    on_checkpoint: Callable[[TrainState], None] | None = None,
    progress: bool = True,
) -> TrainState:
    """Train a preset on (image, heightmap) pairs, or resume ``state`` where it stopped.

    Args:
        preset: ``paper``, ``fast`` or ``tiny``.
        data: training pairs (see ``tactojax.io.load_shape_data``).
        config: optimisation settings; ``config.steps`` is the total, resumed runs included.
        state: a state to resume (from ``tactojax.io.load_train_state``).
        on_checkpoint: called with the state every ``config.checkpoint_every`` steps and at
            the end (e.g. to save it to disk).
        progress: show a progress bar with the loss.

    Returns:
        The final :class:`TrainState`; its ``model`` is ready for ``predict``.
    """
    if len(data) < config.batch_size:
        raise ValueError(f"{len(data)} training pairs is fewer than one batch of {config.batch_size}")
    if state is None:
        state = init_train_state(preset, data, config)
    elif state.model.preset != preset:
        raise ValueError(f"cannot resume a {state.model.preset!r} run as {preset!r}")
    total = config.total_steps(preset)
    pixel_steps = total - config.steps
    steps = {True: make_train_step(config, preset, pixels=True),
             False: make_train_step(config, preset, pixels=False)}
    base_key = jax.random.key(config.seed)
    start = int(state.step)
    bar = tqdm(total=total, initial=start, desc=f"train {preset}", disable=not progress,
               unit="step")
    for step in range(start, total):
        rows = batch_indices(len(data), config.batch_size, config.seed, step)
        if step == pixel_steps and pixel_steps > 0:  # fresh optimiser for the whole-image phase
            state = state.replace(opt_state=make_optimizer(config, preset).init(state.model.params))
        state = steps[step < pixel_steps](state, jax.random.fold_in(base_key, step), data.images_float(rows),
                           data.heightmaps[rows], data.masks[rows].astype(np.float32))
        bar.update(1)
        if (step + 1) % 25 == 0 or step + 1 == total:
            loss, metric = np.asarray(state.history[step])
            name = "slope_rmse" if step < pixel_steps else "patch_rmse_mm"
            bar.set_postfix({"loss": f"{loss:.4f}", name: f"{metric:.4f}"})
        if on_checkpoint is not None and ((step + 1) % config.checkpoint_every == 0
                                          or step + 1 == total):
            on_checkpoint(state)
    bar.close()
    if has_slope_net(preset) and int(state.step) == total:
        state = state.replace(model=fit_mask_threshold(state.model, data, seed=config.seed)[0])
    return state
