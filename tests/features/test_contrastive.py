"""Contrastive training of tactile encoders, pose-neighbour masks and retrieval metrics."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tactojax.features import (
    ContrastiveConfig, ContrastiveState, PlainTiny, ResNetTiny, TouchData, build_encoder, contrastive_loss,
    distillation_loss, encode_images, make_train_step, positive_pair_mask, retrieval_accuracy, train_encoder,
)
from tactojax.io import load_encoder_train_state, save_encoder_train_state
from tactojax.features._contrastive import PoseNeighbours, make_optimizer, resize_images, sample_pairs
from tactojax.features._touches import MM_PER_RADIAN

from test_encoder import random_variables


def _random_touches(seed: int, count: int, objects: int = 2) -> TouchData:
    rng = np.random.default_rng(seed)
    rotations = Rotation.random(count, random_state=seed)
    base = Rotation.from_rotvec(rng.normal(size=3))  # most orientations near one another
    rotations = base * Rotation.from_rotvec(0.3 * rotations.as_rotvec())
    return TouchData(images=np.zeros((count, 4, 4, 3), np.uint8),
                     object_index=rng.integers(0, objects, count).astype(np.int32),
                     positions=rng.uniform(0, 20, (count, 3)).astype(np.float32),
                     rotations=rotations.as_matrix().astype(np.float32),
                     openings=rng.uniform(30, 36, count).astype(np.float32),
                     objects=tuple(f"object{i}" for i in range(objects)))


def _brute_force_mask(touches: TouchData, max_mm: float, max_deg: float, transforms=None) -> np.ndarray:
    """Pose neighbours by direct evaluation (scipy angles, numpy distances); with symmetry
    ``transforms``, against the copy of each pose b of least distance + MM_PER_RADIAN * angle."""
    count = len(touches)
    transforms = np.eye(4)[None] if transforms is None else np.asarray(transforms, np.float64)
    mask = np.zeros((count, count), bool)
    rotations = Rotation.from_matrix(touches.rotations.astype(np.float64))
    for i in range(count):
        best = np.full((count, 3), np.inf)  # cost, distance, angle
        for transform in transforms:
            copy_positions = touches.positions @ transform[:3, :3].T + transform[:3, 3]
            copy_rotations = Rotation.from_matrix(transform[:3, :3]) * rotations
            distance = np.linalg.norm(touches.positions[i].astype(np.float64) - copy_positions, axis=1)
            angle = (rotations[i].inv() * copy_rotations).magnitude()
            cost = distance + MM_PER_RADIAN * angle
            better = cost < best[:, 0]
            best[better] = np.stack([cost, distance, angle], 1)[better]
        same = touches.object_index == touches.object_index[i]
        mask[i] = same & (best[:, 1] <= max_mm) & (np.degrees(best[:, 2]) <= max_deg)
    return mask


def _half_turn_about_z(centre) -> np.ndarray:
    transform = np.eye(4)
    transform[:3, :3] = np.diag([-1.0, -1.0, 1.0])
    transform[:3, 3] = np.asarray(centre) - transform[:3, :3] @ np.asarray(centre)
    return np.stack([np.eye(4), transform]).astype(np.float32)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_positive_pair_mask_matches_brute_force(seed):
    touches = _random_touches(seed, 40)
    expected = _brute_force_mask(touches, 9.0, 30.0)
    got = np.asarray(positive_pair_mask(jnp.asarray(touches.object_index), jnp.asarray(touches.positions),
                                        jnp.asarray(touches.rotations), max_distance_mm=9.0,
                                        max_angle_rad=math.radians(30.0)))
    assert 0 < expected[~np.eye(40, dtype=bool)].sum() < 40 * 39 / 2  # the case is not trivial
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("seed", [0, 1])
def test_symmetric_pose_neighbours_match_brute_force(seed):
    """A half turn about z through (10, 10, 0) makes far-apart poses neighbours."""
    transforms = _half_turn_about_z((10.0, 10.0, 0.0))
    half = _random_touches(seed, 20, objects=1)
    rng = np.random.default_rng(seed)
    turn = transforms[1].astype(np.float64)
    wobble = Rotation.from_rotvec(rng.normal(0.0, 0.2, (20, 3))).as_matrix()
    touches = dataclasses.replace(  # 20 poses and 20 half-turned copies, moved by up to ~15 mm and ~20 deg
        half, images=np.concatenate([half.images, half.images]), object_index=np.zeros(40, np.int32),
        positions=np.concatenate([half.positions, half.positions @ turn[:3, :3].T + turn[:3, 3]
                                  + rng.normal(0.0, 5.0, (20, 3))]).astype(np.float32),
        rotations=np.concatenate([half.rotations, turn[:3, :3] @ half.rotations @ wobble]).astype(np.float32),
        openings=np.concatenate([half.openings, half.openings]), symmetries=(transforms,))
    expected = _brute_force_mask(touches, 9.0, 30.0, transforms)
    assert expected.sum() > _brute_force_mask(touches, 9.0, 30.0).sum()  # the symmetry matters
    got = np.asarray(positive_pair_mask(jnp.asarray(touches.object_index), jnp.asarray(touches.positions),
                                        jnp.asarray(touches.rotations), max_distance_mm=9.0,
                                        max_angle_rad=math.radians(30.0), transforms=jnp.asarray(transforms)))
    np.testing.assert_array_equal(got, expected)
    neighbours = PoseNeighbours(touches, ContrastiveConfig(positive_mm=9.0, positive_deg=30.0))
    rows = np.random.default_rng(seed).choice(40, 12, replace=False)
    np.testing.assert_array_equal(neighbours.mask(rows), expected[np.ix_(rows, rows)])
    for i in range(40):
        np.testing.assert_array_equal(neighbours.of(i), np.flatnonzero(expected[i] & (np.arange(40) != i)))


def test_contrastive_loss_matches_numpy_reference():
    rng = np.random.default_rng(0)
    features = rng.normal(size=(6, 5))
    features /= np.linalg.norm(features, axis=1, keepdims=True)
    positives = np.eye(6, dtype=bool) | (rng.uniform(size=(6, 6)) < 0.3)
    positives = positives | positives.T
    positives[5, :] = positives[:, 5] = False  # a view without positives is skipped
    positives[5, 5] = True
    temperature = 0.2
    losses, hits = [], []
    for i in range(6):
        others = [j for j in range(6) if j != i]
        pos = [j for j in others if positives[i, j]]
        if not pos:
            continue
        logits = {j: features[i] @ features[j] / temperature for j in others}
        log_norm = np.log(sum(np.exp(v) for v in logits.values()))
        losses.append(-np.mean([logits[j] - log_norm for j in pos]))
        hits.append(max(others, key=logits.get) in pos)
    loss, accuracy = contrastive_loss(jnp.asarray(features, jnp.float32), jnp.asarray(positives), temperature)
    np.testing.assert_allclose(float(loss), np.mean(losses), rtol=1e-5)
    np.testing.assert_allclose(float(accuracy), np.mean(hits), rtol=1e-6)


def test_weighted_contrastive_loss_matches_numpy_reference():
    """Float positives: each view's target is its row of weights, normalised; 0/1 weights give
    the boolean loss."""
    rng = np.random.default_rng(1)
    features = rng.normal(size=(6, 4))
    features /= np.linalg.norm(features, axis=1, keepdims=True)
    weights = rng.uniform(size=(6, 6)) * (rng.uniform(size=(6, 6)) < 0.5)
    weights[2, :] = 0.0  # no positive: skipped
    temperature = 0.3
    losses, hits = [], []
    for i in range(6):
        others = [j for j in range(6) if j != i]
        total = sum(weights[i, j] for j in others)
        if total == 0:
            continue
        logits = np.array([features[i] @ features[j] / temperature for j in others])
        log_prob = logits - np.log(np.exp(logits).sum())
        losses.append(-sum(weights[i, j] * lp for j, lp in zip(others, log_prob)) / total)
        hits.append(weights[i, others[int(np.argmax(logits))]] > 0)
    loss, accuracy = contrastive_loss(jnp.asarray(features, jnp.float32), jnp.asarray(weights, jnp.float32), temperature)
    np.testing.assert_allclose(float(loss), np.mean(losses), rtol=1e-5)
    np.testing.assert_allclose(float(accuracy), np.mean(hits), rtol=1e-6)
    mask = weights > 0
    as_bool = contrastive_loss(jnp.asarray(features, jnp.float32), jnp.asarray(mask), temperature)
    as_float = contrastive_loss(jnp.asarray(features, jnp.float32), jnp.asarray(mask, jnp.float32), temperature)
    np.testing.assert_allclose(np.asarray(as_bool), np.asarray(as_float), rtol=1e-6)


def test_soft_pose_weights_decay_with_pose_cost():
    touches = _random_touches(8, 40)
    config = ContrastiveConfig(positive_mm=15.0, positive_deg=40.0, soft_positive_mm=5.0)
    neighbours = PoseNeighbours(touches, config)
    rows = np.arange(40)
    weights = neighbours.weights(rows)
    mask = _brute_force_mask(touches, 15.0, 40.0)
    np.testing.assert_array_equal(weights > 0, mask)
    rotations = Rotation.from_matrix(touches.rotations.astype(np.float64))
    for i, j in zip(*np.nonzero(mask)):
        cost = (np.linalg.norm(touches.positions[i] - touches.positions[j])
                + MM_PER_RADIAN * (rotations[i].inv() * rotations[j]).magnitude())
        assert weights[i, j] == pytest.approx(np.exp(-cost / 5.0), abs=5e-3)  # float32 arccos near 1
    hard = PoseNeighbours(touches, dataclasses.replace(config, soft_positive_mm=0.0))
    np.testing.assert_array_equal(hard.weights(rows), mask.astype(np.float32))


def test_retrieval_accuracy_against_brute_force():
    touches = _random_touches(3, 60)
    features = np.random.default_rng(4).normal(size=(60, 8)).astype(np.float32)
    features /= np.linalg.norm(features, axis=1, keepdims=True)
    result = retrieval_accuracy(features, touches, neighbour_mm=10.0, neighbour_deg=30.0, opening_window_mm=2.0)
    mask = _brute_force_mask(touches, 10.0, 30.0)
    hits, distances = [], []
    for i in range(60):
        candidates = [j for j in range(60) if j != i and touches.object_index[j] == touches.object_index[i]
                      and abs(touches.openings[j] - touches.openings[i]) <= 2.0]
        if candidates:
            best = max(candidates, key=lambda j: features[i] @ features[j])
            hits.append(mask[i, best])
            distances.append(np.linalg.norm(touches.positions[i] - touches.positions[best]))
    assert result["queries"] == len(hits)
    assert result["top1_rate"] == pytest.approx(np.mean(hits))
    assert result["median_top1_mm"] == pytest.approx(np.median(distances), rel=1e-5)
    assert 0.0 < result["chance_rate"] <= result["oracle_rate"] <= 1.0


def test_sample_pairs_are_seeded_pose_neighbours():
    touches = _random_touches(6, 80)
    config = ContrastiveConfig(batch_size=16, positive_mm=9.0, positive_deg=30.0, same_imprint_fraction=0.0)
    neighbours = PoseNeighbours(touches, config)
    anchors, partners = sample_pairs(touches, neighbours, config, step=3)
    again = sample_pairs(touches, neighbours, config, step=3)
    np.testing.assert_array_equal(anchors, again[0])
    np.testing.assert_array_equal(partners, again[1])
    assert len(anchors) == 16 and len(np.unique(touches.object_index[anchors])) == 2
    for anchor, partner in zip(anchors, partners):
        near = neighbours.of(anchor)
        assert partner in near or (partner == anchor and len(near) == 0)
    rows = np.concatenate([anchors, partners])
    np.testing.assert_array_equal(neighbours.mask(rows), _brute_force_mask(touches, 9.0, 30.0)[np.ix_(rows, rows)])


def _synthetic_imprints(count: int = 24) -> tuple[TouchData, np.ndarray]:
    """Imprints of a bump pressed at positions along a line: a dark-edged bright disc on a
    shaded background, 48 x 64 px, moving 1 px per mm; all at one orientation."""
    rng = np.random.default_rng(0)
    rows, cols = np.mgrid[0:48, 0:64]
    background = np.stack([0.4 + 0.1 * rows / 48, 0.5 - 0.1 * cols / 64, np.full((48, 64), 0.45)], -1)
    positions = np.zeros((count, 3), np.float32)
    positions[:, 0] = np.linspace(0.0, 40.0, count)
    images = []
    for x in positions[:, 0]:
        radius = np.hypot(rows - 24, cols - 12 - x)
        bump = np.exp(-((radius - 6) ** 2) / 4.0)[..., None] * np.array([0.3, -0.2, 0.1])
        image = background + bump + rng.normal(0, 0.01, background.shape)
        images.append(np.clip(np.round(255 * image), 0, 255).astype(np.uint8))
    touches = TouchData(images=np.stack(images), object_index=np.zeros(count, np.int32), positions=positions,
                        rotations=np.tile(np.eye(3, dtype=np.float32), (count, 1, 1)),
                        openings=np.full(count, 30.0, np.float32), objects=("bump",))
    return touches, background.astype(np.float32)


def test_train_steps_reduce_the_loss_on_a_synthetic_batch():
    """ResNetTiny on a fixed batch of synthetic imprints: 20 steps lower the InfoNCE loss."""
    touches, background = _synthetic_imprints()
    config = ContrastiveConfig(preset="resnet_tiny", input_size=(32, 32), steps=20, batch_size=12,
                               objects_per_batch=1, positive_mm=4.0, learning_rate=3e-3, warmup_steps=1,
                               color_gain=0.0, noise_std=0.0, max_shift_px=0)  # JAX RNG compiles slowly on CPU
    small = resize_images(touches.images, config.input_size)
    module = ResNetTiny()
    encoder = build_encoder(module, random_variables(module, config.input_size), architecture="resnet_tiny",
                            input_size=config.input_size, mean=(0.0, 0.0, 0.0), std=(0.1, 0.1, 0.1),
                            background=background)
    state = ContrastiveState(encoder=encoder, opt_state=make_optimizer(config).init(encoder.variables["params"]),
                             step=jnp.zeros((), jnp.int32))
    neighbours = PoseNeighbours(touches, config)
    anchors, partners = sample_pairs(touches, neighbours, config, step=0)
    assert (partners != anchors).any()  # neighbours at 1.7 mm are positives
    rows = np.concatenate([anchors, partners])
    batch = {"images": small[rows], "positives": neighbours.mask(rows), "key": jax.random.key(0)}
    train_step = make_train_step(config)
    losses = []
    for _ in range(config.steps):
        state, metrics = train_step(state, batch)
        losses.append(float(metrics["loss"]))
    assert np.isfinite(losses).all()
    assert np.mean(losses[-3:]) < 0.7 * losses[0]
    assert int(state.step) == config.steps
    before, after = encoder.variables["batch_stats"], state.encoder.variables["batch_stats"]
    assert not np.allclose(jax.tree.leaves(before)[0], jax.tree.leaves(after)[0])  # running stats updated
    features = np.asarray(encode_images(state.encoder, touches.images))
    np.testing.assert_allclose(np.linalg.norm(features, axis=1), 1.0, atol=1e-5)


def test_distillation_pulls_the_student_towards_the_teacher_neighbourhoods():
    """A teacher whose features are the touches' positions along the line: distillation-only
    steps lower the distillation loss of a fixed batch."""
    touches, background = _synthetic_imprints()
    angle = touches.positions[:, 0] / 40.0 * np.pi / 2  # 0..90 deg: nearby touches, similar teacher features
    teacher = np.stack([np.cos(angle), np.sin(angle)], 1).astype(np.float32)
    config = ContrastiveConfig(preset="plain_tiny", input_size=(48, 64), steps=25, batch_size=12, objects_per_batch=1,
                               positive_mm=4.0, learning_rate=1e-2, warmup_steps=1, color_gain=0.0, noise_std=0.0,
                               max_shift_px=0, contrastive_weight=0.0, teacher_weight=1.0, teacher_temperature=0.05)
    module = PlainTiny()
    encoder = build_encoder(module, random_variables(module, config.input_size), architecture="plain_tiny",
                            input_size=config.input_size, mean=(0.0, 0.0, 0.0), std=(0.1, 0.1, 0.1), background=background)
    state = ContrastiveState(encoder=encoder, opt_state=make_optimizer(config).init(encoder.variables["params"]),
                             step=jnp.zeros((), jnp.int32))
    neighbours = PoseNeighbours(touches, config)
    anchors, partners = sample_pairs(touches, neighbours, config, step=0)
    rows = np.concatenate([anchors, partners])
    batch = {"images": touches.images[rows], "positives": neighbours.weights(rows), "key": jax.random.key(0),
             "teacher": teacher[rows]}

    def distillation(encoder):
        features = encode_images(encoder, touches.images[rows])
        return float(distillation_loss(features, jnp.asarray(teacher[rows]), config.temperature,
                                       config.teacher_temperature))

    train_step = make_train_step(config)
    before = distillation(encoder)
    for _ in range(config.steps):
        state, metrics = train_step(state, batch)
    assert np.isfinite(float(metrics["loss"]))
    assert distillation(state.encoder) < 0.7 * before


def test_training_resumed_from_a_saved_state_ends_where_an_uninterrupted_run_does(tmp_path):
    touches, background = _synthetic_imprints()
    teacher = np.random.default_rng(0).normal(size=(len(touches), 3)).astype(np.float32)
    teacher /= np.linalg.norm(teacher, axis=1, keepdims=True)
    config = ContrastiveConfig(preset="plain_tiny", input_size=(48, 64), steps=6, batch_size=8, objects_per_batch=1,
                               positive_mm=4.0, warmup_steps=1, color_gain=0.0, noise_std=0.0, max_shift_px=0,
                               teacher_weight=0.5, soft_positive_mm=3.0, eval_every=0, checkpoint_every=3)
    states = []

    def keep(state, history):
        states.append(int(state.step))
        save_encoder_train_state(tmp_path / f"step{int(state.step)}.train-state", state, config, history)

    whole, history = train_encoder(touches, config, background=background, teacher_features=teacher,
                                   on_checkpoint=keep, progress=False)
    assert states == [3, 6] and [entry["step"] for entry in history] == [6]
    state, earlier = load_encoder_train_state(tmp_path / "step3.train-state", config)
    assert int(state.step) == 3 and earlier == []
    resumed, _ = train_encoder(touches, config, background=background, teacher_features=teacher, state=state,
                               history=earlier, progress=False)
    for a, b in zip(jax.tree.leaves(resumed.variables), jax.tree.leaves(whole.variables)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="settings changed"):
        load_encoder_train_state(tmp_path / "step3.train-state", dataclasses.replace(config, steps=7))
    with pytest.raises(ValueError, match="teacher_features"):
        train_encoder(touches, config, background=background, progress=False)


def test_touch_data_select_and_take():
    touches = _random_touches(7, 30, objects=3)
    chosen = touches.select_objects(["object2"])
    assert set(chosen.object_index.tolist()) == {2} and len(chosen) == int((touches.object_index == 2).sum())
    half = touches.take(np.arange(15))
    assert dataclasses.asdict(half)["positions"].shape == (15, 3)
