"""Training a tactile feature encoder: touches at nearby poses look alike, as a teacher sees them.

The paper retrieves imprints with ImageNet features (section VI, CTI). Here a small network is
trained on tactile imprints themselves with a multi-positive InfoNCE loss (SupCon, Khosla et
al. 2020; NT-Xent of SimCLR when every anchor has only its partner): the positives of a touch
are the touches of the *same object* whose sensor poses are within ``positive_mm`` and
``positive_deg`` of its own, up to the object's symmetries (:class:`PoseNeighbours`), so the
features learn what CTI needs, "where on this object was I touched", and not just "which
object". With ``soft_positive_mm`` the positives are weighted by how close their poses are, so
the nearest rank first. Every anchor comes with one partner, a random pose neighbour (or, when
it has none or with probability ``same_imprint_fraction``, another augmented view of the same
imprint). Batches hold ``objects_per_batch`` objects, so most negatives are other places on the
same object, the ones retrieval must tell apart. With ``teacher_weight`` a second term distils
a teacher's neighbourhoods (:func:`~tactojax.features.distillation_loss`, e.g. ImageNet
EfficientNet-Lite0's, whose features are computed once before training). The network sees the
image minus the sensor's no-contact frame (:class:`~tactojax.features._encoder.Encoder`), with
colour, noise and shift augmentation.

Seeded and deterministic: the batch of step ``s`` depends only on ``(seed, s)``, so a run
resumed from a saved state continues exactly.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, Bool, Float, PRNGKeyArray
from tqdm.auto import tqdm

from tactojax import _struct as struct
from tactojax.features._encoder import (
    Encoder, as_unit_range, encode_images, init_encoder, network_input, normalize_features, resize_image,
)
from tactojax.features._distill import distillation_loss
from tactojax.features._touches import MM_PER_RADIAN, TouchData, object_pose_distances, retrieval_accuracy
from tactojax.sensor import augment_colors


@dataclasses.dataclass(frozen=True)
class ContrastiveConfig:
    """Settings of :func:`train_encoder`. The defaults are the shipped ``features-tactile``
    encoder's, which was also given ImageNet EfficientNet-Lite0 as the teacher (``teacher_weight=1``)
    and 5 % of the touches held out (``tactojax train-features data/ycb/* --teacher imagenet:efficientnet-lite0
    --held-out 0.05``, on the YCB scans of ``tactojax info --ycb training``; see the README)."""

    preset: str = "plain_tactile"
    input_size: tuple[int, int] = (120, 160)
    """(h, w) network input, pixels (images are resized once, before training; 120 x 160 is
    gelslim at ``--scale 0.5``, the sensor's own resolution)."""
    steps: int = 4000
    batch_size: int = 32
    """Anchors per step; the network sees twice as many views (anchor and partner)."""
    objects_per_batch: int = 2
    learning_rate: float = 2e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    temperature: float = 0.1
    positive_mm: float = 20.0
    positive_deg: float = 40.0
    """Pose neighbours within these (object frame) are positives: the grasps of a 10 mm grid
    within two steps and the next two yaws (20 deg apart) at the same place."""
    soft_positive_mm: float = 5.0
    """When > 0, pose neighbours are weighted by how close they are, ``exp(-(distance +
    MM_PER_RADIAN * angle) / soft_positive_mm)``, so that the nearest rank first; 0: all alike."""
    symmetric: bool = True
    """Compare poses up to the objects' symmetries (identical imprints are not negatives)."""
    same_imprint_fraction: float = 0.25
    color_gain: float = 0.05
    """Colour augmentation: per-channel gain in 1 +- this, offset in +- 0.4 of it, log-gamma in +- it."""
    noise_std: float = 0.01
    """Gaussian camera noise added to views, [0, 1] units."""
    max_shift_px: int = 2
    """Random translation of views by up to this many input pixels."""
    seed: int = 0
    eval_every: int = 500
    """Validation retrieval every this many steps (0: only at the end)."""
    checkpoint_every: int = 250
    """``train_encoder``'s ``on_checkpoint`` every this many steps (0: only at the end)."""
    contrastive_weight: float = 1.0
    """Weight of the pose-neighbour InfoNCE term."""
    teacher_weight: float = 0.0
    """Weight of the distillation term (:func:`~tactojax.features.distillation_loss`), which
    needs the teacher's features of the training touches; 0: no teacher."""
    teacher_temperature: float = 0.02
    """Softmax temperature of the teacher's similarities in the distillation term."""


@struct.dataclass
class ContrastiveState:
    """What training carries from step to step."""

    encoder: Encoder
    opt_state: Any
    step: Array


def make_optimizer(config: ContrastiveConfig) -> optax.GradientTransformation:
    """AdamW with linear warm-up and cosine decay to 1 % of the peak rate."""
    warmup = min(config.warmup_steps, max(config.steps // 4, 1))
    schedule = optax.warmup_cosine_decay_schedule(
        0.0, config.learning_rate, warmup, max(config.steps, warmup + 1), end_value=0.01 * config.learning_rate)
    return optax.chain(optax.clip_by_global_norm(1.0), optax.adamw(schedule, weight_decay=config.weight_decay))


def contrastive_loss(
    features: Float[Array, "B F"], positives: Bool[Array, "B B"] | Float[Array, "B B"], temperature: float
) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """Multi-positive InfoNCE over a batch of unit features, and the batch's top-1 accuracy.

    ``loss_i = -mean_{p in P(i)} log softmax_{j != i}(f_i . f_j / temperature)_p`` with
    ``P(i)`` the positives of view i other than itself; averaged over views that have one.
    With float ``positives`` (weights >= 0) the mean is weighted: the target of view i's softmax
    is its row of weights, normalised (boolean positives are weights of 1). The accuracy is the
    fraction of those views whose most similar other view is a positive (weight > 0).
    """
    count = features.shape[0]
    off_diagonal = ~jnp.eye(count, dtype=bool)
    logits = jnp.where(off_diagonal, features @ features.T / temperature, -1e9)
    log_prob = logits - jax.nn.logsumexp(logits, axis=1, keepdims=True)
    weights = jnp.where(off_diagonal, jnp.asarray(positives, jnp.float32), 0.0)
    total = jnp.sum(weights, axis=1)
    has = total > 0
    per_view = -jnp.sum(jnp.where(weights > 0, weights * log_prob, 0.0), axis=1) / jnp.where(has, total, 1.0)
    weight = has / jnp.maximum(jnp.sum(has), 1)
    hit = jnp.take_along_axis(weights, jnp.argmax(logits, axis=1)[:, None], axis=1)[:, 0] > 0
    return jnp.sum(weight * per_view), jnp.sum(weight * hit)


def augment_view(
    key: PRNGKeyArray, encoder: Encoder, image: Float[Array, "h w 3"], config: ContrastiveConfig
) -> Float[Array, "h w 3"]:
    """One random view of an image already at the input size: lighting, noise, then shift.

    An augmentation whose size in ``config`` is 0 is skipped (not traced at all).
    """
    color_key, noise_key, shift_key = jax.random.split(key, 3)
    gain = config.color_gain
    view = as_unit_range(image)
    if gain > 0:
        view = augment_colors(color_key, view, max_gain=gain, max_offset=0.4 * gain, max_gamma=gain)
    if config.noise_std > 0:
        view = view + config.noise_std * jax.random.normal(noise_key, view.shape)
    x = network_input(encoder, view)
    pad = config.max_shift_px
    if pad == 0:
        return x
    shift = jax.random.randint(shift_key, (2,), 0, 2 * pad + 1)
    padded = jnp.pad(x, ((pad, pad), (pad, pad), (0, 0)))
    return jax.lax.dynamic_slice(padded, (shift[0], shift[1], 0), x.shape)


def _augments(config: ContrastiveConfig) -> bool:
    return config.color_gain > 0 or config.noise_std > 0 or config.max_shift_px > 0


def batch_loss(params, state: ContrastiveState, batch: dict, config: ContrastiveConfig):
    """(loss, (new batch statistics, top-1 accuracy)) of one batch of views, in train mode."""
    encoder = state.encoder
    if _augments(config):
        keys = jax.random.split(batch["key"], batch["images"].shape[0])
        views = jax.vmap(augment_view, in_axes=(0, None, 0, None))(keys, encoder, batch["images"], config)
    else:
        views = jax.vmap(network_input, in_axes=(None, 0))(encoder, batch["images"])
    variables = {**encoder.variables, "params": params}
    output, updates = encoder.module.apply(variables, views, train=True, mutable=["batch_stats"])
    features = normalize_features(output)
    loss, accuracy = contrastive_loss(features, batch["positives"], config.temperature)
    loss = config.contrastive_weight * loss
    if config.teacher_weight > 0:
        loss = loss + config.teacher_weight * distillation_loss(
            features, batch["teacher"], config.temperature, config.teacher_temperature)
    return loss, (updates.get("batch_stats", {}), accuracy)


def make_train_step(config: ContrastiveConfig):
    """A jitted pure ``train_step(state, batch) -> (state, {"loss", "accuracy"})``.

    ``batch``: ``{"images": (2B, h, w, 3) uint8 at the input size, "positives": (2B, 2B) bool
    pose-neighbour mask or float weights of the views (:meth:`PoseNeighbours.weights`), "key":
    PRNG key}``, and with
    ``config.teacher_weight > 0`` also ``"teacher": (2B, T)`` the teacher's unit features of the views.
    """
    optimizer = make_optimizer(config)

    @jax.jit
    def train_step(state: ContrastiveState, batch: dict):
        params = state.encoder.variables["params"]
        (loss, (batch_stats, accuracy)), grads = jax.value_and_grad(batch_loss, has_aux=True)(
            params, state, batch, config)
        updates, opt_state = optimizer.update(grads, state.opt_state, params)
        variables = {**state.encoder.variables, "params": optax.apply_updates(params, updates)}
        if batch_stats:
            variables["batch_stats"] = batch_stats
        encoder = state.encoder.replace(variables=variables)
        new_state = ContrastiveState(encoder=encoder, opt_state=opt_state, step=state.step + 1)
        return new_state, {"loss": loss, "accuracy": accuracy}

    return train_step


class PoseNeighbours:
    """Which touches of a :class:`TouchData` are pose neighbours of which (same object, up to
    its symmetries): one (K_o, K_o) boolean matrix per object, computed once; with
    ``config.soft_positive_mm`` also how close, as weights ``exp(-cost / soft_positive_mm)``
    with ``cost = distance + MM_PER_RADIAN * angle`` (the closest symmetric copy's)."""

    def __init__(self, touches: TouchData, config: ContrastiveConfig):
        self.object_index = touches.object_index
        self.local = np.zeros(len(touches), np.int64)
        self.matrices: dict[int, np.ndarray] = {}
        self.closeness: dict[int, np.ndarray] = {}
        cos_limit = math.cos(math.radians(config.positive_deg)) - 1e-6
        for obj in np.unique(touches.object_index):
            members = np.flatnonzero(touches.object_index == obj)
            self.local[members] = np.arange(len(members))
            distance, cos_angle = object_pose_distances(touches, members, members, symmetric=config.symmetric)
            self.matrices[int(obj)] = (distance <= config.positive_mm) & (cos_angle >= cos_limit)
            if config.soft_positive_mm > 0:
                cost = distance + MM_PER_RADIAN * np.arccos(np.clip(cos_angle, -1.0, 1.0))
                self.closeness[int(obj)] = np.where(self.matrices[int(obj)], np.exp(-cost / config.soft_positive_mm),
                                                    0.0).astype(np.float32)
        self.members = {obj: np.flatnonzero(touches.object_index == obj) for obj in self.matrices}

    def of(self, index: int) -> np.ndarray:
        """Indices of the pose neighbours of touch ``index``, itself excluded."""
        obj = int(self.object_index[index])
        near = self.members[obj][self.matrices[obj][self.local[index]]]
        return near[near != index]

    def mask(self, rows: np.ndarray) -> np.ndarray:
        """(len(rows), len(rows)) bool: which touches in ``rows`` are pose neighbours (diagonal True)."""
        return self._gather(rows, self.matrices, False)

    def weights(self, rows: np.ndarray) -> np.ndarray:
        """(len(rows), len(rows)) float32 positive weights: the closeness of pose neighbours
        (1 on the diagonal), 0 elsewhere; the mask as 0/1 without ``soft_positive_mm``."""
        if not self.closeness:
            return self.mask(rows).astype(np.float32)
        return self._gather(rows, self.closeness, np.float32(0.0))

    def _gather(self, rows: np.ndarray, matrices: dict, empty) -> np.ndarray:
        objects = self.object_index[rows]
        result = np.full((len(rows), len(rows)), empty)
        for obj in np.unique(objects):
            here = np.flatnonzero(objects == obj)
            local = self.local[rows[here]]
            result[np.ix_(here, here)] = matrices[int(obj)][np.ix_(local, local)]
        return result


def sample_pairs(
    touches: TouchData, neighbours: PoseNeighbours, config: ContrastiveConfig, step: int
) -> tuple[np.ndarray, np.ndarray]:
    """(anchors, partners), (B,) indices each, of training step ``step`` (seeded by it)."""
    rng = np.random.default_rng([config.seed, step])
    objects = np.unique(touches.object_index)
    chosen = rng.choice(objects, min(config.objects_per_batch, len(objects)), replace=False)
    shares = np.diff(np.linspace(0, config.batch_size, len(chosen) + 1).round().astype(int))
    anchors = []
    for obj, share in zip(chosen, shares):
        members = np.flatnonzero(touches.object_index == obj)
        anchors.append(rng.choice(members, share, replace=share > len(members)))
    anchors = np.concatenate(anchors)
    partners = anchors.copy()
    for i, anchor in enumerate(anchors):
        near = neighbours.of(anchor)
        if len(near) and rng.random() >= config.same_imprint_fraction:
            partners[i] = near[rng.integers(len(near))]
    return anchors, partners


def resize_images(images: np.ndarray, size: tuple[int, int], *, batch_size: int = 256) -> np.ndarray:
    """(K, H, W, 3) uint8 -> (K, h, w, 3) uint8 at ``size`` (antialiased bilinear); the images
    themselves when they are at that size already."""
    if tuple(images.shape[1:3]) == tuple(size):
        return images
    resize = jax.jit(jax.vmap(lambda im: resize_image(as_unit_range(im), size)))
    parts = [np.asarray(resize(images[i:i + batch_size])) for i in range(0, len(images), batch_size)]
    return np.clip(np.round(np.concatenate(parts) * 255.0), 0, 255).astype(np.uint8)


def estimate_background(images: np.ndarray, *, max_images: int = 512) -> np.ndarray:
    """The no-contact frame, (H, W, 3) float32 in [0, 1]: the per-pixel median of the images
    (each pixel is untouched in most imprints); a captured frame is better where available."""
    step = max(1, len(images) // max_images)
    return (np.median(images[::step], axis=0) / 255.0).astype(np.float32)


def init_state(config: ContrastiveConfig, background: np.ndarray) -> ContrastiveState:
    """The state at step 0: a randomly initialised encoder (seeded by ``config.seed``) and its optimiser."""
    encoder = init_encoder(jax.random.key(config.seed), config.preset, config.input_size, background=background)
    return ContrastiveState(encoder=encoder, opt_state=make_optimizer(config).init(encoder.variables["params"]),
                            step=jnp.zeros((), jnp.int32))


def train_encoder(
    touches: TouchData,
    config: ContrastiveConfig = ContrastiveConfig(),
    *,
    background: np.ndarray | None = None,
    held_out: np.ndarray | None = None,
    teacher_features: np.ndarray | None = None,
    state: ContrastiveState | None = None,
    history: list[dict] | None = None,
    on_checkpoint: Callable[[ContrastiveState, list[dict]], None] | None = None,
    progress: bool = True,
) -> tuple[Encoder, list[dict]]:
    """Train a tactile encoder with pose-neighbour positives (see the module docstring), or
    resume ``state`` where it stopped (batches and augmentations depend only on the seed and the
    step, so a resumed run continues as if it had not stopped).

    Args:
        touches: training touches (several objects, poses in each object's frame).
        config: settings; ``config.steps`` is the total, resumed runs included.
        background: (H, W, 3) no-contact frame in [0, 1] (default: estimated from the images).
        held_out: (K,) bool, touches not trained on; they are the validation queries,
            retrieved among all touches of their object (:func:`retrieval_accuracy`).
        teacher_features: (K, T) unit features of ``touches`` from a teacher encoder (e.g.
            ImageNet EfficientNet-Lite0), needed when ``config.teacher_weight > 0``.
        state: a state to resume (``tactojax.io.load_encoder_train_state``).
        history: the history of the run being resumed.
        on_checkpoint: called with (state, history) every ``config.checkpoint_every`` steps and
            at the end (e.g. to save them to disk).
        progress: show a progress bar with the loss.

    Returns:
        (the trained encoder, history): one dict per evaluation, ``{"step", "loss",
        "batch_accuracy", and the validation metrics when held_out is given}``.
    """
    held_out = np.zeros(len(touches), bool) if held_out is None else np.asarray(held_out, bool)
    if config.teacher_weight > 0:
        if teacher_features is None or len(teacher_features) != len(touches):
            raise ValueError("teacher_weight > 0 needs teacher_features, one row per touch")
        teacher_train = np.asarray(teacher_features, np.float32)[~held_out]
    small = resize_images(touches.images, config.input_size)
    train = dataclasses.replace(touches.take(~held_out), images=small[~held_out])
    if len(train) < 2:
        raise ValueError(f"{len(train)} training touches: need at least 2")
    neighbours = PoseNeighbours(train, config)
    if state is None:
        state = init_state(config, estimate_background(touches.images) if background is None else background)
    elif state.encoder.architecture != config.preset:
        raise ValueError(f"cannot resume a {state.encoder.architecture!r} run as {config.preset!r}")
    train_step = make_train_step(config)
    base_key = jax.random.key(config.seed + 1)
    history, losses, accuracies = list(history or []), [], []
    start = int(state.step)
    bar = tqdm(total=config.steps, initial=start, desc=f"train {config.preset}", unit="step", disable=not progress)
    for step in range(start, config.steps):
        anchors, partners = sample_pairs(train, neighbours, config, step)
        rows = np.concatenate([anchors, partners])
        batch = {"images": train.images[rows], "positives": neighbours.weights(rows),
                 "key": jax.random.fold_in(base_key, step)}
        if config.teacher_weight > 0:
            batch["teacher"] = teacher_train[rows]
        state, metrics = train_step(state, batch)
        losses.append(metrics["loss"])
        accuracies.append(metrics["accuracy"])
        bar.update(1)
        last = step + 1 == config.steps
        if (step + 1) % 20 == 0 or last:
            bar.set_postfix(loss=f"{float(np.mean(losses[-20:])):.3f}", acc=f"{float(np.mean(accuracies[-20:])):.2f}")
        if last or (config.eval_every and (step + 1) % config.eval_every == 0):
            entry = {"step": step + 1, "loss": float(np.mean(losses[-50:])),
                     "batch_accuracy": float(np.mean(accuracies[-50:]))}
            if held_out.any():
                features = encode_images(state.encoder, small)
                result = retrieval_accuracy(features, touches, queries=held_out, symmetric=config.symmetric)
                entry.update({k: v for k, v in result.items() if k != "per_query"})
                bar.write(f"step {step + 1}: held-out top-1 pose-neighbour rate {entry['top1_rate']:.3f}, "
                          f"median top-1 distance {entry['median_top1_mm']:.1f} mm")
            history.append(entry)
        if on_checkpoint is not None and (last or (config.checkpoint_every and (step + 1) % config.checkpoint_every == 0)):
            on_checkpoint(state, history)
    bar.close()
    return state.encoder, history


def split_held_out(touches: TouchData, fraction: float, *, seed: int = 0) -> np.ndarray:
    """(K,) bool: a random ``fraction`` of each object's touches, held out for validation."""
    rng = np.random.default_rng(seed)
    held_out = np.zeros(len(touches), bool)
    for obj in np.unique(touches.object_index):
        members = np.flatnonzero(touches.object_index == obj)
        held_out[rng.choice(members, int(round(fraction * len(members))), replace=False)] = True
    return held_out
