"""Active touch on the simulated cell: a chosen grasp is executed through the robot interface,
and an active episode fuses every executed grasp in the live localizer, compiling nothing after
its first choice."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax import CompilationCounter
from tactojax.features import encode_images
from tactojax.hardware import APPROACH_MM, active_episode, approach_pose, execute_grasp, simulated_cell
from tactojax.io import load_encoder
from tactojax.localize import BeliefSettings, Localizer
from tactojax.localize.active import ActiveSettings
from tactojax.localize.evaluation import belief_error
from tactojax.localize._candidates import CandidateGrid
from tactojax.objects import get_object
from tactojax.simulate import GraspsProtocol, grasps_plan

TOP_DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # the simulator's gripper at yaw 0


def across_the_box(x=5.0, z=3.0):
    """A top-down grasp across the gum box's thin side (the box at the origin, unturned), mm."""
    rotation = jaxlie.SO3.from_matrix(jnp.asarray(TOP_DOWN, jnp.float32))
    return jaxlie.SE3.from_rotation_and_translation(rotation, jnp.array([x, 0.0, z], jnp.float32))


class LoggingRobot:
    """A robot that logs every call before passing it on."""

    def __init__(self, robot):
        self.robot, self.calls = robot, []

    def move_to(self, T_world_gripper):
        self.calls.append(("move_to", np.asarray(T_world_gripper.wxyz_xyz)))
        self.robot.move_to(T_world_gripper)

    def grasp(self):
        self.calls.append(("grasp", None))
        return self.robot.grasp()

    def release(self):
        self.calls.append(("release", None))
        self.robot.release()


@pytest.mark.parametrize("fingers", [1, 2])
def test_an_executed_grasp_reaches_the_chosen_pose_and_feels_the_object(small_spec, fingers):
    T_grasp = across_the_box()
    with simulated_cell(small_spec, get_object("gum_box"), fingers=fingers) as cell:
        robot = LoggingRobot(cell.robot)
        cameras = [cell.camera] + ([cell.second_camera] if fingers == 2 else [])
        background = [camera.read().image for camera in cameras]

        def hold(opening_mm):
            return [camera.read().image for camera in cameras], cell.scene.T_world_gripper, opening_mm

        executed = execute_grasp(robot, T_grasp, while_closed=hold)
        released = [camera.read().image for camera in cameras]
    assert [name for name, _ in robot.calls] == ["move_to", "move_to", "grasp", "release", "move_to"]
    above = np.asarray(approach_pose(T_grasp).wxyz_xyz)
    np.testing.assert_allclose(robot.calls[0][1], above, atol=1e-5)
    np.testing.assert_allclose(robot.calls[1][1], np.asarray(T_grasp.wxyz_xyz), atol=1e-5)
    np.testing.assert_allclose(robot.calls[4][1], above, atol=1e-5)
    assert above[6] == pytest.approx(3.0 + APPROACH_MM)  # straight above: the approach axis points down
    images, T_held, opening = executed.held
    assert executed.opening_mm == opening and 10.0 < opening < 40.0  # across the box's thin side
    # Held at the chosen pose, re-centred only along the closing axis by the compliant wrist.
    offset = np.asarray((T_grasp.inverse() @ T_held).translation())
    np.testing.assert_allclose(offset[[0, 2]], 0.0, atol=1e-3)
    assert abs(offset[1]) < 15.0
    for finger in range(fingers):  # every gel shows the touch while closed, none after the release
        assert np.abs(images[finger].astype(int) - background[finger]).max() > 20
        np.testing.assert_array_equal(released[finger], background[finger])


def test_a_grasp_that_misses_is_released_and_yields_nothing(small_spec):
    with simulated_cell(small_spec, get_object("gum_box")) as cell:
        robot = LoggingRobot(cell.robot)
        executed = execute_grasp(robot, across_the_box(x=200.0), while_closed=lambda opening: pytest.fail("held"))
    assert executed.opening_mm is None and executed.held is None
    assert [name for name, _ in robot.calls] == ["move_to", "move_to", "grasp", "release", "move_to"]


@pytest.fixture(scope="module")
def active_localizer(gum_box_map, lookup_model, tiny_encoder_path):
    """A live localizer over the gum box, with a small belief that holds two two-finger grasps."""
    encoder = load_encoder(tiny_encoder_path)
    tactile_map = gum_box_map.with_features(encode_images(encoder, gum_box_map.images))
    settings = BeliefSettings(sources=4, grid=CandidateGrid(shift_mm=1.5, shift_steps=1, turn_deg=5.0, turn_steps=1),
                              new_hypotheses=6, registered_sources=2, registration_union=3, hypotheses=8, refine=4,
                              max_touches=4)
    return Localizer([tactile_map], lookup_model, encoder, settings=settings)


def test_an_active_episode_fuses_every_grasp_without_recompiling(small_spec, active_localizer):
    obj = get_object("gum_box")
    plan = grasps_plan(jax.random.key(3), obj, GraspsProtocol(episodes=1, grasps_per_episode=8, turns_deg=(0.0,)))
    settings = ActiveSettings(hypotheses=4, stop_probability=1.01)  # never stop early: run all grasps
    compilations = []  # per episode
    with simulated_cell(small_spec, obj, fingers=2) as cell:
        cell.scene.place_object(jaxlie.SE3(plan.T_world_object.wxyz_xyz[0]))
        for episode in range(2):
            steps = active_episode(jax.random.key(episode), cell.robot, active_localizer, cell.camera,
                                   cell.gripper.opening_mm, cell.poses, plan.T_world_gripper,
                                   second_camera=cell.second_camera, max_grasps=2, candidates=8, settings=settings)
            with CompilationCounter() as counter:
                taken = list(steps)
            compilations.append(counter.count)
            T_world_object = cell.scene.T_world_object
            chosen = [step for step in taken if step.chosen == "active"]
            assert [step.grasp for step in taken][-1] == 2 and len(chosen) == 1
            assert all(not step.stop for step in taken)
            fused = [step for step in taken if step.fused]
            # Every fused grasp is in the belief: two touches (one per finger) each.
            assert active_localizer.grasps == len(fused) >= 1
            assert int(np.sum(np.asarray(taken[-1].belief.touch_valid))) == 2 * len(fused)
            assert all(step.opening_mm is not None for step in fused)
            for step in fused:  # held where commanded, re-centred along the closing axis (y) only
                offset = np.asarray((step.T_world_gripper.inverse() @ step.T_world_gripper_held).translation())
                np.testing.assert_allclose(offset[[0, 2]], 0.0, atol=1e-2)
            assert np.isfinite(chosen[0].gain) and chosen[0].choice_s > 0
            error = float(belief_error(taken[-1].belief, T_world_object))
            assert np.isfinite(error)
            print(f"episode {episode}: {len(taken)} grasps executed, {len(fused)} fused, error {error:.2f} mm, "
                  f"P(within 2 mm) {taken[-1].estimate.probability_within:.2f}")
    # The first episode compiles the proposal and the ranking at its first choice; the second
    # episode (other proposals, the same shapes) compiles nothing.
    assert compilations[0] > 0 and compilations[1] == 0


def test_an_active_episode_checks_its_settings(small_spec, active_localizer):
    with simulated_cell(small_spec, get_object("gum_box")) as cell:
        with pytest.raises(ValueError, match="settings.fingers"):
            next(active_episode(jax.random.key(0), cell.robot, active_localizer, cell.camera, cell.gripper.opening_mm,
                                cell.poses, across_the_box()))
        with pytest.raises(ValueError, match="max_touches"):
            next(active_episode(jax.random.key(0), cell.robot, active_localizer, cell.camera, cell.gripper.opening_mm,
                                cell.poses, across_the_box(), settings=ActiveSettings(fingers=1), max_grasps=5))
