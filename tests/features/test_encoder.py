"""Feature encoders: batched encoding, input pipeline, checkpoints."""

import subprocess
import sys

import flax.linen as nn
import jax
import numpy as np
import pytest

from tactojax.features import (
    build_encoder, encode_image, encode_images, init_encoder, pixel_encoder, with_background,
)
from tactojax.features import ResNetTiny
from tactojax.io import CorruptCheckpointError, bundled_encoders, encoder_metadata, load_encoder, resolve_encoder, save_encoder

SIZE = (32, 32)


class _Unpooled(nn.Module):
    """Returns the image itself, (N, h, w, 3): not an encoder."""

    @nn.compact
    def __call__(self, x):
        return x


@pytest.fixture(scope="module")
def images():
    return np.random.default_rng(0).integers(0, 256, (5, 24, 40, 3), dtype=np.uint8)


@pytest.fixture(scope="module")
def background():
    return np.random.default_rng(1).uniform(0.3, 0.6, (24, 40, 3)).astype(np.float32)


def random_variables(module, input_size, seed: int = 0):
    """He-initialised weights and non-trivial BatchNorm statistics drawn with numpy (no JAX
    RNG: compiling ``module.init`` costs more than the rest of these tests)."""
    rng = np.random.default_rng(seed)
    template = jax.eval_shape(module.init, jax.random.key(0), np.zeros((1, *input_size, 3), np.float32))

    def draw(path, leaf):
        name = jax.tree_util.keystr(path)
        if "kernel" in name:
            return rng.normal(0.0, np.sqrt(2.0 / np.prod(leaf.shape[:-1])), leaf.shape).astype(np.float32)
        if "var" in name or "scale" in name:
            return rng.uniform(0.5, 1.5, leaf.shape).astype(np.float32)
        return rng.normal(0.0, 0.1, leaf.shape).astype(np.float32)  # biases, means

    return jax.tree_util.tree_map_with_path(draw, template)


@pytest.fixture(scope="module")
def encoder(background):
    module = ResNetTiny()
    return build_encoder(module, random_variables(module, SIZE), architecture="resnet_tiny", input_size=SIZE,
                         mean=(0.0, 0.0, 0.0), std=(0.1, 0.1, 0.1), background=background)


def test_encode_images_equals_per_image_loop_and_is_unit_norm(encoder, images):
    batched = np.asarray(encode_images(encoder, images, batch_size=2))  # 2 + 2 + 1 padded
    looped = np.stack([np.asarray(encode_image(encoder, image)) for image in images])
    assert batched.shape == (5, encoder.feature_dim) == (5, 16)
    np.testing.assert_allclose(batched, looped, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(batched, axis=1), 1.0, atol=1e-5)
    assert np.ptp(batched, axis=0).max() > 1e-3  # different images, different features


@pytest.mark.parametrize("batch_size", [1, 3, 4, 64])
def test_features_do_not_depend_on_batch_padding(encoder, images, batch_size):
    reference = np.asarray(encode_images(encoder, images, batch_size=5))
    np.testing.assert_allclose(np.asarray(encode_images(encoder, images, batch_size=batch_size)),
                               reference, atol=1e-5)


def test_float_images_in_unit_range_equal_uint8(encoder, images):
    np.testing.assert_allclose(np.asarray(encode_images(encoder, images.astype(np.float32) / 255.0)),
                               np.asarray(encode_images(encoder, images)), atol=1e-5)


def test_pixel_encoder_matches_numpy_reference(images, background):
    encoder = pixel_encoder((24, 40), background=background)  # same size: no resize
    expected = (images.astype(np.float64) / 255.0 - background).reshape(len(images), -1)
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(np.asarray(encode_images(encoder, images)), expected, atol=1e-5)
    assert with_background(encoder, None).background is None


def test_background_frame_is_resized_like_the_images(images):
    """The frame itself encodes to zero; the frame plus a constant to a constant vector."""
    frame = images[0]
    encoder = with_background(pixel_encoder((12, 20)), frame)
    assert encoder.background.shape == (12, 20, 3)
    np.testing.assert_allclose(np.asarray(encode_images(encoder, frame[None])), 0.0, atol=1e-6)
    brighter = np.clip(frame.astype(np.float32) / 255.0 + 0.01, 0.0, None)  # float input may pass 1
    features = np.asarray(encode_images(encoder, brighter[None]))[0]
    np.testing.assert_allclose(features, 1.0 / np.sqrt(features.size), atol=1e-4)


def test_build_encoder_checks_the_module_and_init_names(encoder):
    wrapped = build_encoder(ResNetTiny(), encoder.variables, architecture="resnet_tiny", input_size=SIZE,
                            mean=(0.5, 0.5, 0.5), std=(0.25, 0.25, 0.25))
    assert wrapped.feature_dim == 16 and wrapped.background is None
    with pytest.raises(ValueError, match="not pooled"):
        build_encoder(_Unpooled(), {}, architecture="x", input_size=SIZE, mean=(0, 0, 0), std=(1, 1, 1))
    with pytest.raises(ValueError, match="unknown encoder architecture"):
        init_encoder(jax.random.key(0), "resnet_huge", SIZE)


def test_checkpoint_round_trip(tmp_path, encoder, images):
    path = save_encoder(tmp_path / "enc.msgpack", encoder, metadata={"note": "test"})
    loaded = load_encoder(path)
    assert (loaded.architecture, loaded.input_size, loaded.mean, loaded.std, loaded.feature_dim) == (
        encoder.architecture, encoder.input_size, encoder.mean, encoder.std, encoder.feature_dim)
    for a, b in zip(jax.tree.leaves(loaded.variables), jax.tree.leaves(encoder.variables)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(np.asarray(loaded.background), np.asarray(encoder.background))
    np.testing.assert_array_equal(np.asarray(encode_images(loaded, images)), np.asarray(encode_images(encoder, images)))
    assert encoder_metadata(path) == {"note": "test"}
    plain = load_encoder(save_encoder(tmp_path / "pixels.msgpack", pixel_encoder((8, 8))))
    assert plain.background is None and plain.feature_dim == 192


def test_corrupt_or_foreign_checkpoints_raise_clear_errors(tmp_path, encoder):
    good = save_encoder(tmp_path / "good.msgpack", encoder).read_bytes()
    truncated = tmp_path / "truncated.msgpack"
    truncated.write_bytes(good[: len(good) // 2])
    with pytest.raises(CorruptCheckpointError, match="not a readable encoder checkpoint"):
        load_encoder(truncated)
    garbage = tmp_path / "garbage.msgpack"
    garbage.write_bytes(b"\x00\x01 not msgpack at all")
    with pytest.raises(CorruptCheckpointError):
        load_encoder(garbage)
    from flax import serialization

    other = tmp_path / "other.msgpack"
    other.write_bytes(serialization.msgpack_serialize({"format": "tactojax-shape-model", "version": 2}))
    with pytest.raises(CorruptCheckpointError, match="not a tactojax-feature-encoder"):
        load_encoder(other)
    payload = serialization.msgpack_restore(good)
    payload["architecture"] = "resnet_tactile"  # weights of resnet_tiny
    mismatch = tmp_path / "mismatch.msgpack"
    mismatch.write_bytes(serialization.msgpack_serialize(payload))
    with pytest.raises(CorruptCheckpointError, match="malformed encoder checkpoint"):
        load_encoder(mismatch)
    with pytest.raises(FileNotFoundError):
        load_encoder(tmp_path / "missing.msgpack")


def test_bundled_tactile_encoder_loads():
    assert "features-tactile" in bundled_encoders()
    encoder = resolve_encoder("bundled:features-tactile")
    assert encoder.architecture == "plain_tactile" and encoder.background is not None
    assert encoder.background.shape == (*encoder.input_size, 3)
    with pytest.raises(FileNotFoundError, match="no bundled encoder"):
        resolve_encoder("bundled:nope")


def test_importing_features_does_not_import_cv2_or_serial():
    code = "import sys, tactojax.features, tactojax.io._encoder; print(sorted({'cv2', 'serial'} & set(sys.modules)))"
    output = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert output.strip() == "[]"
