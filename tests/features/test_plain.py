"""The plain convolutional encoder and the distillation loss, against numpy references."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from tactojax.features import (
    PlainConvNet, PlainTiny, build_encoder, distillation_loss, encode_images, space_to_depth,
)
from tactojax.io import load_encoder, save_encoder

from test_encoder import random_variables


def _space_to_depth_loops(x: np.ndarray, patch: int) -> np.ndarray:
    count, height, width, channels = x.shape
    out = np.zeros((count, height // patch, width // patch, patch * patch * channels), x.dtype)
    for n in range(count):
        for i in range(height // patch):
            for j in range(width // patch):
                for di in range(patch):
                    for dj in range(patch):
                        start = (di * patch + dj) * channels
                        out[n, i, j, start:start + channels] = x[n, i * patch + di, j * patch + dj]
    return out


def _conv_same_loops(x: np.ndarray, kernel: np.ndarray, stride: int) -> np.ndarray:
    """(N, H, W, C) * (k, k, C, D) with TensorFlow/XLA "SAME" padding (extra pixel after)."""
    count, height, width, _ = x.shape
    k = kernel.shape[0]
    rows, cols = -(-height // stride), -(-width // stride)
    pad_rows = max((rows - 1) * stride + k - height, 0)
    pad_cols = max((cols - 1) * stride + k - width, 0)
    padded = np.pad(x, ((0, 0), (pad_rows // 2, pad_rows - pad_rows // 2), (pad_cols // 2, pad_cols - pad_cols // 2),
                        (0, 0)))
    out = np.zeros((count, rows, cols, kernel.shape[-1]))
    for i in range(rows):
        for j in range(cols):
            window = padded[:, i * stride:i * stride + k, j * stride:j * stride + k, :]
            out[:, i, j] = np.einsum("nabc,abcd->nd", window, kernel)
    return out


def _batch_norm(x, stats, params, epsilon=1e-5):
    return (x - stats["mean"]) / np.sqrt(stats["var"] + epsilon) * params["scale"] + params["bias"]


def _plain_reference(variables, x: np.ndarray, module: PlainConvNet) -> np.ndarray:
    """The network's eval-mode forward pass in float64 numpy."""
    params = jax.tree.map(lambda a: np.asarray(a, np.float64), variables["params"])
    stats = jax.tree.map(lambda a: np.asarray(a, np.float64), variables["batch_stats"])
    y = _space_to_depth_loops(x.astype(np.float64), module.patch) @ params["stem"]["kernel"]
    y = np.maximum(_batch_norm(y, stats["stem_bn"], params["stem_bn"]), 0.0)
    for index, (_, stride) in enumerate(module.stages):
        y = _conv_same_loops(y, params[f"conv{index}"]["kernel"], stride)
        y = np.maximum(_batch_norm(y, stats[f"bn{index}"], params[f"bn{index}"]), 0.0)
    pooled = y.mean(axis=(1, 2))
    return pooled @ params["embedding"]["kernel"] + params["embedding"]["bias"]


@pytest.mark.parametrize("patch", [1, 2, 4])
def test_space_to_depth_matches_loops(patch):
    x = np.random.default_rng(0).normal(size=(2, 8, 12, 3)).astype(np.float32)
    np.testing.assert_array_equal(np.asarray(space_to_depth(jnp.asarray(x), patch)), _space_to_depth_loops(x, patch))
    with pytest.raises(ValueError, match="multiple of the patch"):
        space_to_depth(jnp.zeros((1, 6, 8, 3)), 4)


@pytest.mark.parametrize("module,shape", [
    (PlainTiny(), (3, 10, 14, 3)),  # odd sizes after the stem: SAME pads one more after than before
    (PlainConvNet(patch=4, stem_filters=6, stages=((8, 1), (8, 2), (12, 2)), features=5), (2, 24, 32, 3)),
])
@pytest.mark.parametrize("jit", [False, True])
def test_plain_net_matches_numpy_reference(module, shape, jit):
    x = np.random.default_rng(1).normal(size=shape).astype(np.float32)
    variables = random_variables(module, shape[1:3])
    apply = jax.jit(module.apply) if jit else module.apply
    expected = _plain_reference(variables, x, module)
    np.testing.assert_allclose(np.asarray(apply(variables, x)), expected, rtol=2e-4, atol=2e-4)
    looped = np.concatenate([np.asarray(apply(variables, x[i:i + 1])) for i in range(len(x))])  # eval mode: per image
    np.testing.assert_allclose(looped, expected, rtol=2e-4, atol=2e-4)


def test_plain_encoder_checkpoint_round_trip(tmp_path):
    module = PlainTiny()
    background = np.random.default_rng(2).uniform(0.3, 0.6, (12, 16, 3)).astype(np.float32)
    encoder = build_encoder(module, random_variables(module, (12, 16)), architecture="plain_tiny",
                            input_size=(12, 16), mean=(0.0, 0.0, 0.0), std=(0.1, 0.1, 0.1), background=background)
    images = np.random.default_rng(3).integers(0, 256, (4, 12, 16, 3), dtype=np.uint8)
    loaded = load_encoder(save_encoder(tmp_path / "plain.msgpack", encoder))
    assert loaded.architecture == "plain_tiny" and loaded.feature_dim == 8
    np.testing.assert_array_equal(np.asarray(encode_images(loaded, images)), np.asarray(encode_images(encoder, images)))


def _unit(rng, shape):
    x = rng.normal(size=shape)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def _distillation_reference(features, teacher, temperature, teacher_temperature):
    count = len(features)
    total = 0.0
    for i in range(count):
        others = [j for j in range(count) if j != i]
        t = np.array([teacher[i] @ teacher[j] / teacher_temperature for j in others])
        s = np.array([features[i] @ features[j] / temperature for j in others])
        p = np.exp(t - t.max()) / np.exp(t - t.max()).sum()
        log_q = s - s.max() - np.log(np.exp(s - s.max()).sum())
        total += np.sum(p * (np.log(p) - log_q))
    return total / count


def test_distillation_loss_matches_numpy_reference_and_vanishes_on_the_teacher():
    rng = np.random.default_rng(4)
    features, teacher = _unit(rng, (7, 5)), _unit(rng, (7, 9))
    loss = distillation_loss(jnp.asarray(features, jnp.float32), jnp.asarray(teacher, jnp.float32), 0.1, 0.05)
    np.testing.assert_allclose(float(loss), _distillation_reference(features, teacher, 0.1, 0.05), rtol=1e-4)
    assert float(loss) > 0.0
    same = distillation_loss(jnp.asarray(teacher, jnp.float32), jnp.asarray(teacher, jnp.float32), 0.05, 0.05)
    assert abs(float(same)) < 1e-5  # KL of a distribution with itself


def test_distillation_loss_gradients():
    jax.config.update("jax_enable_x64", True)
    try:
        rng = np.random.default_rng(5)
        features, teacher = jnp.asarray(_unit(rng, (5, 4))), jnp.asarray(_unit(rng, (5, 6)))
        check_grads(lambda f: distillation_loss(f, teacher, 0.2, 0.1), (features,), order=1, modes=("rev",))
        gradient = jax.grad(lambda t: distillation_loss(features, t, 0.2, 0.1))(teacher)
        np.testing.assert_array_equal(np.asarray(gradient), 0.0)  # the teacher is a fixed target
    finally:
        jax.config.update("jax_enable_x64", False)
