"""Gripper kinematics against a numpy reference built from the documented frame convention.

Convention (tactojax/geometry/_kinematics.py): the sensor finger sits at y = +opening / 2 of the
gripper frame; sensor x = gripper x, sensor y = gripper z, sensor z = -gripper y. The opposite
finger is that finger turned by pi about the gripper z axis.
"""

from __future__ import annotations

import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
from hypothesis import given, settings

from tactojax.geometry import T_gripper_sensor, gripper_pose, opposite_sensor_pose, sensor_pose

BATCH_SHAPES = [(), (1,), (3, 1, 2)]
SEEDS = st.integers(min_value=0, max_value=2**31 - 1)
ATOL = 2e-5  # float32, millimetre-scale translations

# Shared jitted functions (compiled once per batch shape for the whole module).
_sensor_pose_jit = jax.jit(sensor_pose)
_opposite_pose_jit = jax.jit(opposite_sensor_pose)
_gripper_pose_jit = jax.jit(gripper_pose)
_T_gripper_sensor_jit = jax.jit(T_gripper_sensor)


# ---------------------------------------------------------------- numpy reference

def _quat_wxyz_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternions (..., 4) wxyz, textbook formula."""
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def _homogeneous(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    shape = np.broadcast_shapes(rotation.shape[:-2], translation.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = rotation
    T[..., :3, 3] = translation
    T[..., 3, 3] = 1.0
    return T


def _reference_T_gripper_sensor(opening: np.ndarray) -> np.ndarray:
    """From the docstring: columns = sensor axes in the gripper frame, origin at y = opening/2."""
    x_s = np.array([1.0, 0.0, 0.0])   # sensor x = gripper x
    y_s = np.array([0.0, 0.0, 1.0])   # sensor y (image rows) = gripper z (approach)
    z_s = np.array([0.0, -1.0, 0.0])  # sensor z (out of the gel) = -gripper y
    rotation = np.stack([x_s, y_s, z_s], axis=-1)
    opening = np.asarray(opening, np.float64)
    translation = np.stack([np.zeros_like(opening), opening / 2, np.zeros_like(opening)], -1)
    return _homogeneous(np.broadcast_to(rotation, opening.shape + (3, 3)), translation)


def _reference_flip_z() -> np.ndarray:
    return _homogeneous(np.diag([-1.0, -1.0, 1.0]), np.zeros(3))


def _random_poses(rng: np.random.Generator, shape: tuple[int, ...]):
    """Random gripper poses as (jaxlie.SE3, numpy 4x4 reference) and openings in mm."""
    wxyz = rng.normal(size=shape + (4,))
    wxyz /= np.linalg.norm(wxyz, axis=-1, keepdims=True)
    xyz = rng.uniform(-200.0, 200.0, size=shape + (3,))
    opening = rng.uniform(0.0, 110.0, size=shape)
    T = jaxlie.SE3(jnp.asarray(np.concatenate([wxyz, xyz], -1), jnp.float32))
    reference = _homogeneous(_quat_wxyz_to_matrix(wxyz), xyz)
    return T, reference, opening


def _assert_pose_close(actual: jaxlie.SE3, expected: np.ndarray, atol: float = ATOL) -> None:
    matrix = np.asarray(actual.as_matrix(), np.float64)
    assert matrix.shape == expected.shape
    np.testing.assert_allclose(matrix[..., :3, :3], expected[..., :3, :3], atol=1e-5)
    np.testing.assert_allclose(matrix[..., :3, 3], expected[..., :3, 3], atol=atol, rtol=1e-6)


# ---------------------------------------------------------------- tests

def test_T_gripper_sensor_axes_match_docstring():
    T = T_gripper_sensor(jnp.asarray(40.0))
    R = np.asarray(T.rotation().as_matrix())
    np.testing.assert_allclose(R @ [1, 0, 0], [1, 0, 0], atol=1e-6)   # x_s = x_g
    np.testing.assert_allclose(R @ [0, 1, 0], [0, 0, 1], atol=1e-6)   # y_s = z_g
    np.testing.assert_allclose(R @ [0, 0, 1], [0, -1, 0], atol=1e-6)  # z_s = -y_g
    np.testing.assert_allclose(np.asarray(T.translation()), [0, 20.0, 0], atol=1e-6)
    # Right-handed proper rotation.
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-6)


@pytest.mark.parametrize("shape", BATCH_SHAPES)
@settings(max_examples=5, deadline=None)
@given(seed=SEEDS)
def test_T_gripper_sensor_vs_reference(shape, seed):
    opening = np.random.default_rng(seed).uniform(0.0, 110.0, size=shape)
    expected = _reference_T_gripper_sensor(opening)
    _assert_pose_close(T_gripper_sensor(jnp.asarray(opening, jnp.float32)), expected)
    _assert_pose_close(_T_gripper_sensor_jit(jnp.asarray(opening, jnp.float32)), expected)


@pytest.mark.parametrize("shape", BATCH_SHAPES)
@settings(max_examples=5, deadline=None)
@given(seed=SEEDS)
def test_sensor_pose_vs_reference(shape, seed):
    T, reference, opening = _random_poses(np.random.default_rng(seed), shape)
    expected = reference @ _reference_T_gripper_sensor(opening)
    opening_j = jnp.asarray(opening, jnp.float32)
    _assert_pose_close(sensor_pose(T, opening_j), expected)
    _assert_pose_close(_sensor_pose_jit(T, opening_j), expected)


@pytest.mark.parametrize("shape", BATCH_SHAPES)
@settings(max_examples=5, deadline=None)
@given(seed=SEEDS)
def test_opposite_sensor_pose_vs_reference(shape, seed):
    T, reference, opening = _random_poses(np.random.default_rng(seed), shape)
    expected = reference @ _reference_flip_z() @ _reference_T_gripper_sensor(opening)
    opening_j = jnp.asarray(opening, jnp.float32)
    _assert_pose_close(opposite_sensor_pose(T, opening_j), expected)
    _assert_pose_close(_opposite_pose_jit(T, opening_j), expected)


@pytest.mark.parametrize("shape", BATCH_SHAPES)
@settings(max_examples=5, deadline=None)
@given(seed=SEEDS)
def test_round_trip(shape, seed):
    T, reference, opening = _random_poses(np.random.default_rng(seed), shape)
    opening_j = jnp.asarray(opening, jnp.float32)
    for fn_sensor, fn_gripper in ((sensor_pose, gripper_pose), (_sensor_pose_jit, _gripper_pose_jit)):
        back = fn_gripper(fn_sensor(T, opening_j), opening_j)
        _assert_pose_close(back, reference, atol=5e-5)


def test_fingers_face_each_other():
    """Both gels sit `opening` apart on the closing axis, z axes pointing at each other."""
    opening = 37.0
    T = jaxlie.SE3.identity()
    a = sensor_pose(T, jnp.asarray(opening))
    b = opposite_sensor_pose(T, jnp.asarray(opening))
    pa, pb = np.asarray(a.translation()), np.asarray(b.translation())
    np.testing.assert_allclose(pa, [0, opening / 2, 0], atol=1e-5)
    np.testing.assert_allclose(pb, [0, -opening / 2, 0], atol=1e-5)
    za = np.asarray(a.rotation().as_matrix())[:, 2]
    zb = np.asarray(b.rotation().as_matrix())[:, 2]
    np.testing.assert_allclose(za, (pb - pa) / opening, atol=1e-6)
    np.testing.assert_allclose(zb, (pa - pb) / opening, atol=1e-6)
    # Both images' rows run along the approach direction.
    np.testing.assert_allclose(np.asarray(a.rotation().as_matrix())[:, 1], [0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(np.asarray(b.rotation().as_matrix())[:, 1], [0, 0, 1], atol=1e-6)


@settings(max_examples=3, deadline=None)
@given(seed=SEEDS)
def test_vmap_matches_python_loop(seed):
    T, _, opening = _random_poses(np.random.default_rng(seed), (4,))
    opening_j = jnp.asarray(opening, jnp.float32)
    for fn in (sensor_pose, opposite_sensor_pose, gripper_pose):
        batched = jax.vmap(fn)(T, opening_j).as_matrix()
        looped = jnp.stack([
            fn(jax.tree.map(lambda x: x[i], T), opening_j[i]).as_matrix() for i in range(4)
        ])
        np.testing.assert_allclose(np.asarray(batched), np.asarray(looped), atol=1e-5)
