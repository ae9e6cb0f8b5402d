"""Exploration protocols: plan geometry and simulated records."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from tactojax.objects import get_object
from tactojax.simulate import CalibrationProtocol, MappingProtocol, calibration_plan, mapping_plan, simulate_protocol


def test_mapping_plan_is_an_equispaced_grid_over_the_object():
    box = get_object("cuboid")  # 80 x 20 x 25 mm
    plan = mapping_plan(box, MappingProtocol(grid_mm=10.0, yaws_deg=(0.0,), turns_deg=(0.0,)))
    # 80 mm along x -> 9 columns, 25 mm tall -> 3 rows.
    assert len(plan) == 9 * 3
    np.testing.assert_allclose(np.unique(np.asarray(plan.grid_u_mm)), np.arange(-40.0, 41.0, 10.0), atol=1e-4)
    np.testing.assert_allclose(np.unique(np.asarray(plan.grid_v_mm)), [-10.0, 0.0, 10.0], atol=1e-4)
    # The gripper approaches from above with its closing axis along world y.
    R = np.asarray(plan.T_world_gripper.rotation().as_matrix())
    np.testing.assert_allclose(R[:, :, 2], np.tile([0.0, 0.0, -1.0], (len(plan), 1)), atol=1e-6)
    np.testing.assert_allclose(np.abs(R[:, :, 1]), np.tile([0.0, 1.0, 0.0], (len(plan), 1)), atol=1e-6)


def test_mapping_plan_covers_every_yaw_and_turn():
    plan = mapping_plan(get_object("cylinder"), MappingProtocol())
    assert set(np.round(np.rad2deg(np.asarray(plan.yaw_rad))).astype(int)) == {-20, 0, 20}
    assert set(np.round(np.rad2deg(np.asarray(plan.turn_rad))).astype(int)) == {0, 90, 180, 270}


def test_calibration_plan_faces_down_within_the_field_of_view(small_spec):
    sphere = get_object("calib_sphere")
    protocol = CalibrationProtocol(touches=50)
    plan = calibration_plan(jax.random.key(0), sphere, small_spec, protocol)
    z_axis = np.asarray(plan.T_world_sensor_start.rotation() @ jnp.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(z_axis, np.tile([0.0, 0.0, -1.0], (50, 1)), atol=1e-6)
    fov_x, fov_y = small_spec.field_of_view_mm
    assert np.all(np.abs(np.asarray(plan.offset_x_mm)) <= 0.3 * fov_x)
    assert np.all(np.abs(np.asarray(plan.offset_y_mm)) <= 0.3 * fov_y)
    depth = np.asarray(plan.depth_mm)
    assert depth.min() >= 0.5 and depth.max() <= 1.5


def test_calibration_touches_of_a_sphere_give_spherical_caps(small_spec):
    sphere = get_object("calib_sphere")  # radius 6 mm
    protocol = CalibrationProtocol(touches=8)
    records = next(simulate_protocol(jax.random.key(1), small_spec, sphere, protocol, batch_size=8, progress=False))
    assert records["image"].dtype == np.uint8 and records["image"].shape == (8, 60, 80, 3)
    # Deepest gel indentation is the depth; the contact disc has radius sqrt(2 R d - d^2).
    np.testing.assert_allclose(records["heightmap"].max(axis=(1, 2)), records["depth_mm"], atol=2e-3)
    depth = records["depth_mm"]
    expected_area = np.pi * (2 * 6.0 * depth - depth**2)
    area = records["mask"].sum(axis=(1, 2)) * small_spec.mm_per_px**2
    np.testing.assert_allclose(area, expected_area, rtol=0.12)
    # The sensor ends up pressed onto the sphere: its gel plane sits R - d above the centre, up
    # to where the pixel grid samples the apex (pixels 0.4 mm apart: < 7e-3 mm).
    T_world_sensor = jaxlie.SE3(jnp.asarray(records["T_world_sensor"]))
    np.testing.assert_allclose(np.asarray(T_world_sensor.translation())[:, 2], 6.0 - depth, atol=1e-2)
    # The sphere's centre appears at the planned offset in the sensor frame.
    centre_in_sensor = np.asarray(T_world_sensor.inverse() @ jnp.zeros(3))
    np.testing.assert_allclose(centre_in_sensor[:, 0], records["offset_x_mm"], atol=1e-3)
    np.testing.assert_allclose(centre_in_sensor[:, 1], records["offset_y_mm"], atol=1e-3)


def test_mapping_grid_for_is_the_finest_grid_within_the_budget():
    from tactojax.simulate import mapping_grid_for

    obj = get_object("cuboid")
    protocol = MappingProtocol(grid_mm=10.0, yaws_deg=(0.0,), turns_deg=(0.0, 90.0))
    full = len(mapping_plan(obj, protocol).yaw_rad)
    assert mapping_grid_for(obj, protocol, full) == 10.0  # within budget already
    grid = mapping_grid_for(obj, protocol, full // 3)
    assert grid > 10.0 and (grid - 10.0) % 0.5 == 0.0
    assert len(mapping_plan(obj, MappingProtocol(grid, (0.0,), (0.0, 90.0))).yaw_rad) <= full // 3
    assert len(mapping_plan(obj, MappingProtocol(grid - 0.5, (0.0,), (0.0, 90.0))).yaw_rad) > full // 3
