"""Which grasp next: expected gains of candidate grasps under a hand-made belief."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax.localize import BeliefCalibration, BeliefSettings, empty_belief
from tactojax.localize.active import (ActiveSettings, closes_across_felt, map_marching_grid, next_grasp,
                                     observe_failed_grasp, predict_grasp, propose_grasps, should_stop)
from tactojax.objects import get_object

from active_fixtures import truth_map

TOP_DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # the simulator's gripper at yaw 0


@pytest.fixture(scope="module")
def gum_box(small_spec):
    view = truth_map(small_spec, get_object("gum_box"), grid_mm=15.0)
    return view, map_marching_grid(view)


def grasp(x, z, yaw_deg=0.0):
    """A top-down grasp centred at (x, 0, z) in the world, mm."""
    rotation = jaxlie.SO3.from_z_radians(np.deg2rad(yaw_deg)) @ jaxlie.SO3.from_matrix(jnp.asarray(TOP_DOWN))
    return jaxlie.SE3.from_rotation_and_translation(rotation, jnp.array([x, 0.0, z], jnp.float32))


def stack(poses):
    return jaxlie.SE3(jnp.stack([T.wxyz_xyz for T in poses]))


def belief_over(view, T_world_objects, weights):
    """A belief over the given object poses (the world's origin as the reference sensor, a 5 x 5
    cloud of its points 20 mm across as the touch)."""
    belief = empty_belief(view, BeliefSettings(hypotheses=len(weights), max_touches=2))
    xy = np.stack(np.meshgrid(np.linspace(-10, 10, 5), np.linspace(-10, 10, 5)), -1).reshape(-1, 2)
    contact = jnp.zeros_like(belief.evidence.contact).at[0, :25, :2].set(jnp.asarray(xy, jnp.float32))
    evidence = belief.evidence.replace(contact=contact, contact_valid=belief.evidence.contact_valid.at[0, :25].set(True))
    log_weights = jnp.log(jnp.asarray(weights, jnp.float32) / np.sum(weights))
    # Scales of its own (not the library's default): the gains below are sized for them.
    calibration = BeliefCalibration(temperature=jnp.float32(0.1), appearance=jnp.float32(0.0),
                                    fusion_exponent=jnp.float32(0.0))
    return belief.replace(T_object_reference=stack(T_world_objects).inverse(), log_weights=log_weights,
                          evidence=evidence, touch_valid=belief.touch_valid.at[0].set(True), calibration=calibration)


def shift(x=0.0, y=0.0, z=0.0):
    return jaxlie.SE3.from_translation(jnp.array([x, y, z], jnp.float32))


@pytest.mark.parametrize("objective", ["within", "entropy"])
def test_the_grasp_that_separates_two_modes_is_chosen(gum_box, objective):
    view, grid = gum_box
    # Two modes 6 mm apart along the box's long axis: a grasp in the middle of its broad face
    # feels the same face at both; one over its end (x = 40.5 mm) tells them apart.
    belief = belief_over(view, [shift(), shift(x=6.0)], [0.5, 0.5])
    candidates = [grasp(x, z) for x in (-12.0, 0.0, 12.0) for z in (-8.0, 8.0)] + [grasp(40.0, 0.0)]
    ranking = next_grasp(view, grid, belief, stack(candidates), ActiveSettings(hypotheses=2, objective=objective))
    gain = np.asarray(ranking.gain)
    assert int(ranking.order[0]) == len(candidates) - 1
    assert gain[-1] > 0.2 * (1.0 if objective == "within" else np.log(2.0))
    assert np.all(np.abs(gain[:-1]) < 0.5 * gain[-1])
    assert np.all(np.asarray(ranking.closes) == 1.0)


def test_grasps_related_by_the_symmetry_get_equal_gains(gum_box):
    view, grid = gum_box
    # Modes 4 mm apart vertically (a shift that commutes with the box's half turn about z); a
    # grasp near the top edge and its image under the half turn about the vertical.
    belief = belief_over(view, [shift(), shift(z=4.0)], [0.6, 0.4])
    half_turn = jaxlie.SE3.from_rotation(jaxlie.SO3.from_z_radians(np.pi))
    near_edge = grasp(20.0, 18.0, yaw_deg=10.0)
    candidates = stack([near_edge, half_turn @ near_edge, grasp(0.0, -5.0)])
    ranking = next_grasp(view, grid, belief, candidates, ActiveSettings(hypotheses=2))
    gain = np.asarray(ranking.gain)
    assert gain[0] > 0.1
    # Equal up to the map's discretisation (its grid cells and the ray grid are not placed
    # symmetrically: 15 % apart here); the grasp that cannot tell the modes apart is far below.
    np.testing.assert_allclose(gain[1], gain[0], rtol=0.2)
    assert abs(gain[2]) < 0.5 * gain[0]  # a grasp that cannot tell the modes apart gains less


def test_proposals_close_on_the_object_and_the_stopping_rule(gum_box):
    view, grid = gum_box
    belief = belief_over(view, [shift(), shift(x=6.0)], [0.97, 0.03])
    poses, closes = propose_grasps(jax.random.key(0), view, grid, belief, 16, ActiveSettings(hypotheses=2))
    assert poses.wxyz_xyz.shape == (16, 7) and np.mean(np.asarray(closes)) > 0.9
    assert bool(should_stop(belief, 0.95)) and not bool(should_stop(belief_over(view, [shift(), shift(x=6.0)],
                                                                                  [0.5, 0.5]), 0.95))


def test_a_failed_grasp_rules_out_the_poses_where_it_would_have_closed(gum_box):
    view, grid = gum_box
    # Two modes 60 mm apart along the box's long axis (81 mm): a grasp over the box's centre at
    # the first closes on it, and misses the second (the box then spans x = 19.5-100.5 mm).
    belief = belief_over(view, [shift(), shift(x=60.0)], [0.5, 0.5])
    belief = belief.replace(log_evidence=jnp.float32(-3.0))
    settings = ActiveSettings(hypotheses=2, predicted_close_misses=0.05)
    at_centre = grasp(0.0, 0.0)
    gel = tuple(n * view.mm_per_px for n in view.packed_heightmaps.shape[1:])  # (height, width) mm
    closes = [bool(predict_grasp(grid, view.surface, T, at_centre, gel, settings.prediction, fingers=2).valid)
              for T in (shift(), shift(x=60.0))]
    assert closes == [True, False]
    after = observe_failed_grasp(view, grid, belief, at_centre, settings)
    # Bayes by hand: P(failure | pose) is 0.05 where the grasp closes, 1 where it misses.
    np.testing.assert_allclose(np.asarray(after.probabilities), [0.025 / 0.525, 0.5 / 0.525], rtol=1e-5)
    assert float(after.log_evidence) == pytest.approx(-3.0 + np.log(0.525), abs=1e-5)
    np.testing.assert_array_equal(np.asarray(after.T_object_reference.wxyz_xyz),
                                  np.asarray(belief.T_object_reference.wxyz_xyz))
    # A grasp that would close at both poses leaves their odds as they were; an empty belief stays empty.
    over_both = grasp(25.0, 0.0)
    assert all(bool(predict_grasp(grid, view.surface, T, over_both, gel, settings.prediction, fingers=2).valid)
               for T in (shift(), shift(x=60.0)))
    both = observe_failed_grasp(view, grid, belief, over_both, settings)
    np.testing.assert_allclose(np.asarray(both.probabilities), [0.5, 0.5], rtol=1e-5)
    empty = empty_belief(view, BeliefSettings(hypotheses=2, max_touches=2))
    assert not np.any(np.isfinite(np.asarray(observe_failed_grasp(view, grid, empty, at_centre, settings).log_weights)))


# A touch of the gum box's broad face (y = -11.5 mm) at the origin, pressing along +y: the
# sensor's x along world x, its z (into the object) along world y.
FACE_SENSOR = jaxlie.SE3.from_rotation_and_translation(
    jaxlie.SO3.from_matrix(jnp.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])),
    jnp.array([0.0, -11.5, 0.0]))


def test_a_grasp_closes_across_a_felt_contact_only_at_right_angles_through_it():
    points, pressing = jnp.array([[0.0, -11.5, 0.0]]), jnp.array([[0.0, 1.0, 0.0]])
    valid, gel = jnp.array([True]), (24.0, 32.0)

    def across(T):
        return bool(closes_across_felt(T, points, pressing, valid, gel))

    assert across(grasp(0.0, 0.0, yaw_deg=90.0))  # closing along x, through the point
    assert across(grasp(0.0, 0.0, yaw_deg=60.0))  # 30 degrees off the right angle
    assert not across(grasp(0.0, 0.0, yaw_deg=0.0))  # along the felt grasp's own axis
    assert not across(grasp(0.0, 11.0, yaw_deg=90.0))  # the point 11 mm up: past the gel's border less the margin
    two = jnp.array([[0.0, -11.5, 0.0], [80.0, -11.5, 0.0]])  # a second felt point beyond a jaw
    assert not bool(closes_across_felt(grasp(0.0, 0.0, yaw_deg=90.0), two, jnp.tile(pressing, (2, 1)),
                                       jnp.array([True, True]), gel))
    assert bool(closes_across_felt(grasp(0.0, 0.0, yaw_deg=90.0), two, jnp.tile(pressing, (2, 1)),
                                   jnp.array([True, False]), gel))  # ... unless it is not valid


def face_touch_belief(view, found_offset, found_slope=0.0):
    """A belief at the box's true pose (the world's) after a touch of its broad face
    (:data:`FACE_SENSOR`), its search's P(found) set by ``found_offset`` and ``found_slope``."""
    belief = belief_over(view, [shift(), shift(z=4.0)], [0.6, 0.4])
    contact = jnp.zeros_like(belief.evidence.contact)
    evidence = belief.evidence.replace(contact=contact,
                                       contact_valid=jnp.zeros_like(belief.evidence.contact_valid).at[0, 0].set(True))
    T_object_reference = jax.vmap(lambda T: T @ FACE_SENSOR)(belief.T_object_reference)
    return belief.replace(evidence=evidence, T_world_reference=FACE_SENSOR, T_object_reference=T_object_reference,
                          calibration=belief.calibration.replace(found_offset=jnp.float32(found_offset),
                                                                 found_slope=jnp.float32(found_slope)))


def test_where_the_search_likely_missed_a_grasp_across_a_felt_contact_comes_first(gum_box):
    view, grid = gum_box
    # Near the top edge (it tells the two modes, 4 mm apart vertically, apart) and across the
    # felt contact (closing along the box's 81 mm length, through the felt point: its end faces
    # are the same at both modes).
    candidates = stack([grasp(20.0, 18.0, yaw_deg=10.0), grasp(0.0, 0.0, yaw_deg=90.0)])
    settings = ActiveSettings(hypotheses=2)
    sure = next_grasp(view, grid, face_touch_belief(view, 20.0), candidates, settings)  # P(found) = 1
    assert np.asarray(sure.across_felt).tolist() == [False, True]
    np.testing.assert_allclose(np.asarray(sure.close_probability), np.asarray(sure.closes), atol=1e-6)
    assert int(sure.order[0]) == 0 and float(sure.gain[0]) > float(sure.gain[1])
    # P(found) = 0.2 now, 0.87 after one more grasp (3 touches): the grasp across the felt contact
    # closes whatever the pose, and is likelier to leave the belief right.
    lost = next_grasp(view, grid, face_touch_belief(view, -1.386, 3.0), candidates, settings)
    np.testing.assert_allclose(np.asarray(lost.close_probability), [0.2, 1.0], atol=1e-3)
    assert int(lost.order[0]) == 1


def test_proposals_across_a_felt_contact_close_across_it(gum_box):
    view, grid = gum_box
    settings = ActiveSettings(hypotheses=2)
    belief = face_touch_belief(view, 0.0)
    poses, _ = propose_grasps(jax.random.key(1), view, grid, belief, 16, settings)
    ranking = next_grasp(view, grid, belief, poses, settings)
    assert np.all(np.asarray(ranking.across_felt)[:8])  # the first round(16 * across_felt)


def test_the_predicted_clearance_is_the_jaws_distance_from_the_object(gum_box):
    view, grid = gum_box
    gel = tuple(n * view.mm_per_px for n in view.packed_heightmaps.shape[1:])
    settings = ActiveSettings().prediction

    def clearance(T_world_object, T_world_gripper):
        return float(predict_grasp(grid, view.surface, T_world_object, T_world_gripper, gel, settings).clearance_mm)

    # Open jaws 110 mm apart; the box 23 mm thick across its broad faces, 81 mm long.
    assert clearance(shift(), grasp(0.0, 0.0)) == pytest.approx((110.0 - 23.0) / 2, abs=1.0)
    assert clearance(shift(), grasp(0.0, 0.0, yaw_deg=90.0)) == pytest.approx((110.0 - 81.0) / 2, abs=1.0)
    assert clearance(shift(y=20.0), grasp(0.0, 0.0)) == pytest.approx((110.0 - 23.0) / 2 - 20.0, abs=1.0)
    # A jaw starting just inside the box's face (at y = 55 mm, the face at 55.5 mm). The map knows
    # the surface only within 1.5 mm of it: a jaw starting deeper inside is not seen.
    assert clearance(shift(y=44.0), grasp(0.0, 0.0)) == 0.0
