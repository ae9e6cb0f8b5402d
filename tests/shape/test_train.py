"""Training: it learns, it is deterministic, and a resumed run equals an uninterrupted one."""

import jax
import numpy as np
import pytest
from flax import serialization

from tactojax.io import CorruptCheckpointError, load_shape_model, load_train_state, save_shape_model, save_train_state
from tactojax.shape import TrainConfig, evaluate_shape_model, predict_batch, split_held_out, train_shape_model

CONFIG = TrainConfig(steps=4, pixel_steps=300, batch_size=4, pixels_per_image=256, warmup_steps=5,
                     learning_rate=1e-2,
                     checkpoint_every=152)


@pytest.fixture(scope="module")
def trained(shape_data):
    train, test = split_held_out(shape_data, 8)
    saved = []
    state = train_shape_model("tiny", train, CONFIG, progress=False, on_checkpoint=saved.append)
    return train, test, state, saved


def test_training_learns(trained):
    train, test, state, _ = trained
    history = np.asarray(state.history)
    assert history.shape == (CONFIG.total_steps("tiny"), 2) and np.all(np.isfinite(history))
    # The slope error falls during the pixel phase.
    assert history[290:300, 1].mean() < 0.4 * history[:5, 1].mean()
    untrained = train_shape_model("tiny", train, TrainConfig(steps=1, pixel_steps=0, batch_size=4),
                                  progress=False)
    before = np.nanmean(evaluate_shape_model(untrained.model, test)["patch_rmse"])
    after = np.nanmean(evaluate_shape_model(state.model, test)["patch_rmse"])
    assert after < 0.3 * before


def test_resumed_run_matches(trained, tmp_path):
    train, _, state, saved = trained
    assert [int(s.step) for s in saved] == [152, 304]
    path = save_train_state(tmp_path / "state", saved[0], CONFIG)
    resumed = train_shape_model("tiny", train, CONFIG, state=load_train_state(path, CONFIG), progress=False)
    for a, b in zip(jax.tree.leaves(state.model.params), jax.tree.leaves(resumed.model.params)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(np.asarray(state.history), np.asarray(resumed.history), rtol=1e-6)
    with pytest.raises(ValueError, match="training settings changed"):
        load_train_state(path, TrainConfig(steps=5))


def test_checkpoint_round_trip_and_corruption(trained, tmp_path):
    _, test, state, _ = trained
    path = save_shape_model(tmp_path / "model.msgpack", state.model, metadata={"note": "test"})
    loaded = load_shape_model(path)
    assert loaded.preset == "tiny" and loaded.mm_per_px == state.model.mm_per_px
    assert loaded.color_gain == state.model.color_gain == TrainConfig().color_gain
    # On the device once: a model of NumPy arrays is copied to an accelerator at every call.
    assert all(isinstance(leaf, jax.Array) for leaf in jax.tree.leaves((loaded.params, loaded.background)))
    images = test.images_float(slice(0, 2))
    for a, b in zip(predict_batch(state.model, images), predict_batch(loaded, images)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # Version-1 checkpoints (no stored gain) were all trained with gain 8.
    payload = serialization.msgpack_restore(path.read_bytes())
    payload["version"] = 1
    del payload["color_gain"]
    (tmp_path / "v1.msgpack").write_bytes(serialization.msgpack_serialize(payload))
    assert load_shape_model(tmp_path / "v1.msgpack").color_gain == 8.0
    path.write_bytes(path.read_bytes()[:100])
    with pytest.raises(CorruptCheckpointError):
        load_shape_model(path)
    (tmp_path / "text.msgpack").write_text("hello")
    with pytest.raises(CorruptCheckpointError):
        load_shape_model(tmp_path / "text.msgpack")
    with pytest.raises(FileNotFoundError):
        load_shape_model(tmp_path / "missing.msgpack")
