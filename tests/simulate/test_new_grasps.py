"""New-grasps protocol: episodes of continuous grasps, one or two sensing fingers."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
import scipy.ndimage

from tactojax.geometry import heightmap_to_points, opposite_sensor_pose, sensor_pose
from tactojax.objects import Sphere, TactileObject, Union, get_object, placed
from tactojax.simulate import GraspConfig, GraspsProtocol, grasps_plan, simulate_grasps, simulate_protocol

EPISODES, GRASPS = 2, 3


def simulate(spec, protocol, seed=0, obj="cylinder", config=GraspConfig()):
    obj = get_object(obj) if isinstance(obj, str) else obj
    batches = list(simulate_protocol(jax.random.key(seed), spec, obj, protocol, config=config,
                                     batch_size=8, progress=False))
    return {name: np.concatenate([b[name] for b in batches]) for name in batches[0]}


@pytest.fixture(scope="module")
def two_fingers(small_spec):
    return simulate(small_spec, GraspsProtocol(episodes=EPISODES, grasps_per_episode=GRASPS, fingers=2))


@pytest.fixture(scope="module")
def one_finger(small_spec):
    return simulate(small_spec, GraspsProtocol(episodes=EPISODES, grasps_per_episode=GRASPS))


def se3(records, name):
    return jaxlie.SE3(jnp.asarray(records[name]))


def capped_cylinder_sdf(points, radius, half_length):
    """Signed distance to a solid cylinder along x (numpy, closed form)."""
    q = np.stack([np.linalg.norm(points[:, 1:], axis=-1) - radius, np.abs(points[:, 0]) - half_length], -1)
    return np.minimum(q.max(-1), 0.0) + np.linalg.norm(np.maximum(q, 0.0), axis=-1)


@pytest.mark.parametrize("fingers", [1, 2])
def test_every_episode_has_its_grasps_in_order(one_finger, two_fingers, fingers):
    records = one_finger if fingers == 1 else two_fingers
    assert len(records["image"]) == EPISODES * GRASPS * fingers
    np.testing.assert_array_equal(records["episode"], np.repeat(np.arange(EPISODES), GRASPS * fingers))
    np.testing.assert_array_equal(records["grasp"], np.tile(np.repeat(np.arange(GRASPS), fingers), EPISODES))
    np.testing.assert_array_equal(records["finger"], np.tile(np.arange(fingers), EPISODES * GRASPS))
    assert set(records["object_id"]) == {"cylinder"}
    # One object pose per episode: a mapping turn about world z.
    per_episode = records["T_world_object"].reshape(EPISODES, GRASPS * fingers, 7)
    np.testing.assert_array_equal(per_episode, np.repeat(per_episode[:, :1], GRASPS * fingers, axis=1))
    turn = records["turn_rad"]
    assert set(np.round(np.rad2deg(turn)).astype(int)) <= {0, 90, 180, 270}
    expected = jaxlie.SE3.from_rotation(jaxlie.SO3.from_z_radians(jnp.asarray(turn)))
    np.testing.assert_allclose(np.asarray(expected.as_matrix()), np.asarray(se3(records, "T_world_object").as_matrix()),
                               atol=1e-6)
    # Both fingers of a grasp share the gripper pose, the opening and the depth.
    for name in ("T_world_gripper", "opening_mm", "depth_mm", "yaw_rad"):
        per_grasp = records[name].reshape(EPISODES * GRASPS, fingers, *records[name].shape[1:])
        np.testing.assert_array_equal(per_grasp, np.repeat(per_grasp[:, :1], fingers, axis=1))


def test_plan_is_continuous_over_the_object_and_the_yaw_range():
    cuboid = get_object("cuboid")  # 80 x 20 x 25 mm
    protocol = GraspsProtocol(episodes=40, grasps_per_episode=50, yaw_range_deg=20.0)
    plan = grasps_plan(jax.random.key(0), cuboid, protocol)
    yaw = np.rad2deg(np.asarray(plan.yaw_rad))
    assert np.all(np.abs(yaw) <= 20.0) and yaw.min() < -19.0 and yaw.max() > 19.0
    assert len(np.unique(yaw)) > 0.99 * len(plan)  # not a few fixed yaws
    # The centre covers the box as seen in the gripper plane (u along the gripper's x axis).
    T = plan.T_world_gripper
    x_axis = np.asarray(T.rotation().as_matrix())[:, :, 0]
    y_axis = np.asarray(T.rotation().as_matrix())[:, :, 1]
    position = np.asarray(T.translation())
    np.testing.assert_allclose(np.sum(position * x_axis, -1), plan.u_mm, atol=1e-4)
    np.testing.assert_allclose(position[:, 2], plan.v_mm, atol=1e-5)
    np.testing.assert_allclose(np.sum(position * y_axis, -1), 0.0, atol=1e-4)  # centred on the box
    v = np.asarray(plan.v_mm)
    assert v.min() >= -12.5 and v.max() <= 12.5 and v.min() < -12.0 and v.max() > 12.0
    # Along the length (turn 0 or 180, the gripper's x axis near world x) u spans about ±40 mm.
    turn = np.round(np.rad2deg(np.asarray(plan.turn_rad))).astype(int)
    along = np.isin(turn, [0, 180])
    u = np.asarray(plan.u_mm)
    half_extent = 40.0 * np.cos(np.deg2rad(yaw)) + 10.0 * np.abs(np.sin(np.deg2rad(yaw)))
    assert np.all(np.abs(u[along]) <= half_extent[along] + 1e-4)
    assert np.abs(u[along]).max() > 38.0 and len(np.unique(u)) > 0.99 * len(plan)
    # Positions off any grid: a 10 mm grid would put every u at one phase.
    phase = np.mod(u, 10.0)
    assert phase.std() > 2.0
    # Each episode keeps one turn; every turn is drawn.
    per_episode = turn.reshape(40, 50)
    assert np.all(per_episode == per_episode[:, :1])
    assert set(per_episode[:, 0]) == {0, 90, 180, 270}


def test_plan_candidates_are_deterministic_and_extend_the_same_sequence():
    cylinder = get_object("cylinder")
    protocol = GraspsProtocol(episodes=3, grasps_per_episode=4)
    first = grasps_plan(jax.random.key(5), cylinder, protocol, candidates=6)
    again = grasps_plan(jax.random.key(5), cylinder, protocol, candidates=6)
    later = grasps_plan(jax.random.key(5), cylinder, protocol, candidates=2, start=4)
    other = grasps_plan(jax.random.key(6), cylinder, protocol, candidates=6)
    poses = np.asarray(first.T_world_gripper.wxyz_xyz).reshape(3, 6, 7)
    np.testing.assert_array_equal(poses, np.asarray(again.T_world_gripper.wxyz_xyz).reshape(3, 6, 7))
    np.testing.assert_array_equal(poses[:, 4:], np.asarray(later.T_world_gripper.wxyz_xyz).reshape(3, 2, 7))
    assert not np.allclose(poses, np.asarray(other.T_world_gripper.wxyz_xyz).reshape(3, 6, 7))
    np.testing.assert_array_equal(np.asarray(first.episode), np.repeat(np.arange(3), 6))
    np.testing.assert_array_equal(np.asarray(later.candidate), np.tile([4, 5], 3))


def test_simulation_is_deterministic_for_a_seed(small_spec, two_fingers):
    protocol = GraspsProtocol(episodes=EPISODES, grasps_per_episode=GRASPS, fingers=2)
    again = simulate(small_spec, protocol)
    for name, values in two_fingers.items():
        np.testing.assert_array_equal(again[name], values, err_msg=name)
    other = simulate(small_spec, protocol, seed=1)
    assert not np.allclose(other["T_world_gripper"], two_fingers["T_world_gripper"])


@pytest.mark.parametrize("fingers", [1, 2])
def test_finger_poses_follow_the_gripper_kinematics(one_finger, two_fingers, fingers):
    records = one_finger if fingers == 1 else two_fingers
    T_world_gripper, opening = se3(records, "T_world_gripper"), jnp.asarray(records["opening_mm"])
    T_world_sensor = records["T_world_sensor"]
    finger = records["finger"]
    expected = np.where(finger[:, None] == 0, np.asarray(sensor_pose(T_world_gripper, opening).wxyz_xyz),
                        np.asarray(opposite_sensor_pose(T_world_gripper, opening).wxyz_xyz))
    np.testing.assert_allclose(T_world_sensor, expected, atol=1e-5)
    # The gripper comes from above, within the yaw range, its x axis at the recorded yaw.
    R = np.asarray(T_world_gripper.rotation().as_matrix())
    np.testing.assert_allclose(R[:, :, 2], np.tile([0.0, 0.0, -1.0], (len(R), 1)), atol=1e-6)
    yaw = records["yaw_rad"]
    assert np.all(np.abs(yaw) <= np.deg2rad(20.0))
    np.testing.assert_allclose(R[:, :2, 0], np.stack([np.cos(yaw), np.sin(yaw)], -1), atol=1e-6)
    assert len(np.unique(yaw)) == EPISODES * GRASPS


@pytest.mark.parametrize("fingers", [1, 2])
def test_every_imprint_lies_on_the_cylinder(small_spec, one_finger, two_fingers, fingers):
    """Independent check: contact points of the true heightmaps, taken to the object frame,
    lie on the closed-form cylinder; the two fingers press opposite sides by the same depth."""
    records = one_finger if fingers == 1 else two_fingers
    cylinder = get_object("cylinder")
    radius, half_length = cylinder.parameters["radius_mm"], cylinder.extents[0] / 2
    T_object_sensor = se3(records, "T_world_object").inverse() @ se3(records, "T_world_sensor")
    T_gripper_sensor = se3(records, "T_world_gripper").inverse() @ se3(records, "T_world_sensor")
    for index in range(len(records["image"])):
        heightmap, mask = records["heightmap"][index], records["mask"][index]
        assert mask.sum() > 20
        points = np.asarray(jax.tree.map(lambda x: x[index], T_object_sensor)
                            @ heightmap_to_points(jnp.asarray(heightmap), small_spec.mm_per_px))
        distance = np.abs(capped_cylinder_sdf(points.reshape(-1, 3), radius, half_length).reshape(mask.shape))
        # Exact where the gel conforms; its elastic smoothing lifts it off near the contact's rim.
        assert distance[mask].max() < 0.15
        interior = scipy.ndimage.binary_erosion(mask, iterations=2)
        assert distance[interior].max(initial=0.0) < 0.01
        # The gel pressed in by the grasp's depth.
        np.testing.assert_allclose(heightmap.max(), records["depth_mm"][index], atol=1e-3)
        # Sensor jaw at +y of the gripper frame, opposite jaw at -y, each opening / 2 away.
        y = float(jax.tree.map(lambda x: x[index], T_gripper_sensor).translation()[1])
        sign = 1.0 if records["finger"][index] == 0 else -1.0
        np.testing.assert_allclose(y, sign * records["opening_mm"][index] / 2, atol=1e-4)


def test_two_gels_close_about_one_depth_further_than_a_rigid_pad(one_finger, two_fingers):
    # Same seed, same candidates: each grasp's opening shrinks by the second gel's depth, up to
    # where the rigid pad's coarser ray grid (24 x 32) finds the first contact.
    opening_1 = one_finger["opening_mm"]
    opening_2 = two_fingers["opening_mm"][two_fingers["finger"] == 0]
    np.testing.assert_allclose(one_finger["T_world_object"], two_fingers["T_world_object"][::2])
    np.testing.assert_allclose(opening_1 - opening_2, 1.0, atol=0.25)


def test_missed_candidates_are_replaced_by_the_next_ones(small_spec):
    # Two balls 120 mm apart: a grasp centred between them misses (the gel is 32 mm wide).
    balls = Union(tuple(placed(Sphere(jnp.float32(8.0)), translation=(x, 0.0, 0.0)) for x in (-60.0, 60.0)))
    two_balls = TactileObject("two_balls", balls, np.array([[-68.0, -8.0, -8.0], [68.0, 8.0, 8.0]]))
    protocol = GraspsProtocol(episodes=EPISODES, grasps_per_episode=GRASPS, turns_deg=(0.0, 180.0))
    records = simulate(small_spec, protocol, seed=3, obj=two_balls)
    assert len(records["image"]) == EPISODES * GRASPS
    # simulate_protocol draws candidates with the first half of its key (as the other protocols plan).
    plan = grasps_plan(jax.random.split(jax.random.key(3))[0], two_balls, protocol, candidates=16)
    valid = np.asarray(simulate_grasps(jax.random.key(0), small_spec, two_balls, plan.T_world_object,
                                       plan.T_world_gripper).valid).reshape(EPISODES, 16)
    assert not valid[:, :GRASPS].all()  # some of the first candidates missed
    yaws = np.asarray(plan.yaw_rad).reshape(EPISODES, 16)
    expected = [yaws[e][valid[e]][:GRASPS] for e in range(EPISODES)]
    np.testing.assert_array_equal(records["yaw_rad"].reshape(EPISODES, GRASPS), expected)


def test_an_object_the_gripper_cannot_grasp_is_a_clear_error(small_spec):
    narrow = GraspConfig(max_opening_mm=40.0)  # the cylinder is 50 mm across at its narrowest
    with pytest.raises(ValueError, match="in a row"):
        simulate(small_spec, GraspsProtocol(episodes=1, grasps_per_episode=1), config=narrow)


def test_bad_protocols_are_refused():
    cylinder = get_object("cylinder")
    for protocol in (GraspsProtocol(fingers=3), GraspsProtocol(episodes=0), GraspsProtocol(turns_deg=())):
        with pytest.raises(ValueError):
            grasps_plan(jax.random.key(0), cylinder, protocol)


def test_an_episode_redraws_a_placement_the_gripper_cannot_grasp(small_spec):
    # A 60 mm gripper closes on the gum box across its 23 mm (turn 0) but not along its 81 mm
    # (turn 90): an episode that drew turn 90 draws again instead of giving up (issue 28).
    from tactojax.simulate._protocols import grasp_candidates

    protocol = GraspsProtocol(episodes=4, grasps_per_episode=1, turns_deg=(0.0, 90.0))
    obj = get_object("gum_box")
    first = grasp_candidates(jax.random.split(jax.random.key(0))[0], obj, protocol, np.arange(4), np.zeros(4))
    assert np.any(np.isclose(np.rad2deg(np.asarray(first.turn_rad)), 90.0))  # some episode drew the bad turn
    records = simulate(small_spec, protocol, obj="gum_box", config=GraspConfig(max_opening_mm=60.0))
    assert np.allclose(np.rad2deg(records["turn_rad"]), 0.0) and len(records["turn_rad"]) == 4
    assert np.array_equal(np.unique(records["episode"]), np.arange(4))
