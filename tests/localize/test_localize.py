"""``localize``: several touches are the update applied touch by touch; bad input is a clear error."""

import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax.localize import empty_belief, localize
from tactojax.localize._localize import jitted_update

T_WORLD_OBJECT = jaxlie.SE3.exp(jnp.array([12.0, -30.0, 85.0, 0.2, 0.4, -0.9]))
"""Where the object sits in the robot's frame (the touches' poses come in that frame)."""


@pytest.fixture(scope="module")
def touches(synthetic):
    """Three touches of the bumps and their sensor poses in the world."""
    poses = [synthetic.sensor_pose(-2.0, 1.0), synthetic.sensor_pose(3.0, -2.5, 5.0),
             synthetic.sensor_pose(0.5, 2.0, -4.0)]
    return [synthetic.touch(synthetic.bumps, T) for T in poses], [T_WORLD_OBJECT @ T for T in poses], poses


def _assert_same_belief(a, b):
    for name in ("log_weights", "log_evidence", "touch_valid"):
        np.testing.assert_allclose(np.asarray(getattr(a, name)), np.asarray(getattr(b, name)), rtol=1e-5, atol=1e-5)
    for name in ("T_object_reference", "T_reference_touch", "T_world_reference"):
        np.testing.assert_allclose(np.asarray(getattr(a, name).wxyz_xyz), np.asarray(getattr(b, name).wxyz_xyz),
                                   atol=1e-4)


def test_several_touches_are_the_update_touch_by_touch(bumps_view, touches, belief_settings):
    touch_list, world_poses, object_poses = touches
    fused = localize(bumps_view, touch_list, world_poses, settings=belief_settings)
    # update_belief folded by hand (the jitted update_belief the module shares, so that the
    # test compiles it once: localize() adds the checks, the poses and the touch order).
    belief = empty_belief(bumps_view, belief_settings)
    for touch, T in zip(touch_list, world_poses):
        belief = jitted_update(bumps_view, belief, touch, T, belief_settings)
    _assert_same_belief(fused, belief)
    # The same poses as one batched SE3; a belief continued touch by touch.
    batched = jaxlie.SE3(jnp.stack([T.wxyz_xyz for T in world_poses]))
    _assert_same_belief(localize(bumps_view, touch_list, batched, settings=belief_settings), fused)
    first = localize(bumps_view, touch_list[0], world_poses[0], settings=belief_settings)
    continued = localize(bumps_view, touch_list[1:], world_poses[1:], belief=first, settings=belief_settings)
    _assert_same_belief(continued, fused)
    # max_touches is 2: the belief remembers the first (the reference) and the last touch.
    assert int(fused.touches) == 2
    # It found the object: the touches' poses in the object frame, and the object in the world.
    for t, T_true in ((0, object_poses[0]), (1, object_poses[2])):
        assert np.linalg.norm(np.asarray(fused.touch_pose(t).translation() - T_true.translation())) < 0.5
    assert np.linalg.norm(np.asarray(fused.T_world_object.translation() - T_WORLD_OBJECT.translation())) < 0.5


def test_a_single_touch_needs_no_pose_and_a_touch_without_contact_changes_nothing(bumps_view, touches,
                                                                                  belief_settings):
    touch_list, world_poses, object_poses = touches
    alone = localize(bumps_view, touch_list[0], settings=belief_settings)  # the belief's world: the sensor's
    np.testing.assert_allclose(np.asarray(alone.T_world_reference.wxyz_xyz),
                               np.asarray(jaxlie.SE3.identity().wxyz_xyz), atol=1e-6)
    assert np.linalg.norm(np.asarray(alone.best.translation() - object_poses[0].translation())) < 0.5
    nothing = touch_list[1].replace(mask=jnp.zeros_like(touch_list[1].mask),
                                    heightmap=jnp.zeros_like(touch_list[1].heightmap))
    same = localize(bumps_view, nothing, world_poses[1], belief=alone, settings=belief_settings)
    _assert_same_belief(same, alone)


def test_bad_input_is_a_clear_error(bumps_view, touches, belief_settings):
    touch_list, world_poses, _ = touches
    run = lambda t, T=None, **options: localize(bumps_view, t, T, settings=belief_settings, **options)  # noqa: E731
    no_contact = [t.replace(mask=jnp.zeros_like(t.mask)) for t in touch_list[:2]]
    with pytest.raises(ValueError, match="no touch shows contact"):
        run(no_contact, world_poses[:2])
    with pytest.raises(ValueError, match="need their sensor poses"):
        run(touch_list[:2])
    with pytest.raises(ValueError, match="2 touches but 3 sensor poses"):
        run(touch_list[:2], world_poses)
    with pytest.raises(ValueError, match="2 touches but 1 sensor poses"):
        run(touch_list[:2], world_poses[0])
    with pytest.raises(ValueError, match=r"touch 0 has a \(23, 32\) heightmap"):
        run(touch_list[0].replace(heightmap=touch_list[0].heightmap[:-1], mask=touch_list[0].mask[:-1]))
    with pytest.raises(ValueError, match="features"):
        run(touch_list[0].replace(feature=jnp.zeros(5)))
    with pytest.raises(ValueError, match="touch 1 holds NaN"):
        nan_heightmap = touch_list[1].heightmap.at[3, 4].set(jnp.nan)
        run([touch_list[0], touch_list[1].replace(heightmap=nan_heightmap)], world_poses[:2])
    with pytest.raises(ValueError, match="NaN"):
        run(touch_list[0].replace(opening=jnp.float32(jnp.nan)))
    with pytest.raises(ValueError, match="sensor pose of touch 1"):
        run(touch_list[:2], [world_poses[0], jaxlie.SE3(jnp.full(7, jnp.nan))])
