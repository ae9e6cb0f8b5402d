"""The live loop. The Localizer: a settled grasp updates the belief once, as ``localize`` does
stage by stage; grasps fuse by the kinematics; nothing recompiles; bad frames are clear errors.
The Tracker: it starts from the belief of a settled grasp, then follows; contact lost ends the
track and the belief. (One module: both share the programs of one session fixture.)"""

import dataclasses

import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from tactojax import CompilationCounter
from tactojax.features import encode_image
from tactojax.geometry import sensor_pose
from tactojax.localize import Touch, localize
from tactojax.localize._evaluate import pose_errors
from tactojax.mapping import observed_contact
from tactojax.shape import predict

T_WORLD_OBJECT = jaxlie.SE3.exp(jnp.array([120.0, -40.0, 210.0, 0.1, -0.3, 0.7]))
"""Where the object stands in the robot's frame during the grasps."""


@pytest.fixture(scope="module")
def live(live_tracker):
    tracker, maps, encoder = live_tracker
    return tracker.localizer, maps, encoder


def _background(model):
    return np.round(np.asarray(model.background) * 255).astype(np.uint8)


def _grasp_indices(tactile_map, count):
    """``count`` imprints spread over the map, for successive grasps."""
    valid = np.flatnonzero(np.asarray(tactile_map.imprint_valid))
    return valid[np.linspace(0, len(valid) - 1, count + 2).astype(int)[1:-1]]


def _symmetric_error(view, tactile_map, index, T_estimate, T_true):
    """The paper's RMSE of the imprint's cloud at the estimated and the true pose, up to symmetry, mm."""
    return float(pose_errors(tactile_map.points[index], tactile_map.valid[index], T_true, T_estimate,
                             view.symmetries)["symmetric_rmse"])


def _touches(belief) -> int:
    """How many touches a belief holds (NumPy: nothing to compile)."""
    return int(np.sum(np.asarray(belief.touch_valid)))


def test_grasps_fuse_resets_and_no_contact_never_recompile(live, lookup_model, grasp_frames):
    """From the first frame after start-up (this module's first test): the frames of three
    grasps, releases, a reset and a forced fusion compile nothing (everything else, the frames
    and the errors, is made outside the counted block)."""
    localizer, maps, _ = live
    settle = localizer.live.settle_frames
    background = _background(lookup_model)
    indices = [int(i) for i in _grasp_indices(maps[1], 3)]
    grasps = [grasp_frames(maps[1], index, T_WORLD_OBJECT) for index in indices]
    localizer.reset()
    settled, released, touches = [], [], []
    with CompilationCounter() as compiles:
        for image, opening, T_world_gripper, _ in grasps:
            estimates = [localizer(image, opening, T_world_gripper) for _ in range(settle + 1)]
            settled.append(estimates)
            released.append(localizer(background, opening, T_world_gripper))  # the gripper opens
            touches.append([_touches(b) for b in localizer.beliefs])
        # The object is moved: forget it, and start again from one grasp.
        localizer.reset()
        after_reset = (localizer.grasps, [_touches(b) for b in localizer.beliefs])
        image, opening, T_world_gripper, _ = grasps[0]
        fused = localizer.fuse(image, opening, T_world_gripper)  # without waiting for it to settle
        again = [localizer(image, opening, T_world_gripper) for _ in range(settle + 1)]
    assert compiles.messages == []
    for g, estimates in enumerate(settled):  # each grasp updates the belief once, when it settles
        assert [e.updated for e in estimates] == [False] * (settle - 1) + [True, False]
        assert all(e.object_id == maps[1].object_id and e.grasps == g + 1 for e in estimates[settle - 1:])
        assert not released[g].contact and not released[g].updated
        assert released[g].T_world_object is not None  # the belief stands between grasps
        # The gum box's belief holds every grasp; the cylinder's those before it dropped out.
        assert touches[g][1] == min(g + 1, localizer.settings.max_touches) and 1 <= touches[g][0] <= touches[g][1]
    assert after_reset == (0, [0, 0])
    assert fused.updated and fused.grasps == 1 and not any(e.updated for e in again)
    errors = [_symmetric_error(localizer.stack.map(1), maps[1], index, estimates[settle - 1].T_object_sensor, T_true)
              for index, estimates, (_, _, _, T_true) in zip(indices, settled, grasps)]
    assert max(errors) < 2.0, errors


def test_a_settled_grasp_updates_the_belief_once_as_localize_does(live, lookup_model, grasp_frames):
    localizer, maps, encoder = live
    settle = localizer.live.settle_frames
    index = int(_grasp_indices(maps[1], 1)[0])
    image, opening, T_world_gripper, T_true = grasp_frames(maps[1], index, T_WORLD_OBJECT)
    localizer.reset()
    estimates = [localizer(image, opening, T_world_gripper) for _ in range(settle + 2)]
    assert [e.updated for e in estimates] == [False] * (settle - 1) + [True, False, False]
    assert [e.grasps for e in estimates] == [0] * (settle - 1) + [1, 1, 1]
    assert all(e.contact for e in estimates)
    assert estimates[0].object_id is None and estimates[0].T_world_object is None
    assert [_touches(b) for b in localizer.beliefs] == [1, 1]  # every map's belief, once
    estimate = estimates[settle - 1]
    assert estimate.object_id == maps[1].object_id and estimate.object_probabilities[maps[1].object_id] > 0.5
    assert sum(estimate.object_probabilities.values()) == pytest.approx(1.0)

    # Stage by stage: shape model, contact, encoder, kinematics, then localize() on the map.
    pixels = jnp.asarray(image, jnp.float32) / 255.0
    heightmap, mask = predict(lookup_model, pixels)
    mask = observed_contact(pixels, lookup_model.background, mask, lookup_model.mm_per_px)
    touch = Touch(heightmap=heightmap, mask=mask, feature=encode_image(encoder, image), opening=jnp.float32(opening))
    T_world_sensor = sensor_pose(T_world_gripper, jnp.float32(opening))
    # The map on its own, padded to the stack's window (a map of fewer imprints than the belief's
    # sources retrieves from the padding too: 16 imprints here).
    view = localizer.stack.map(1).padded_to(localizer.stack.window_size)
    reference = localize(view, touch, T_world_sensor, settings=localizer.settings)
    belief = localizer.beliefs[1]
    # Two compilations of one update: float32 rounding, which ICP's iterations amplify to a few
    # micrometres on the least likely (poorly constrained) hypotheses.
    np.testing.assert_allclose(np.asarray(belief.log_weights), np.asarray(reference.log_weights), atol=2e-3)
    np.testing.assert_allclose(np.asarray(belief.T_object_reference.wxyz_xyz),
                               np.asarray(reference.T_object_reference.wxyz_xyz), atol=5e-3)
    np.testing.assert_allclose(np.asarray(estimate.T_world_object.wxyz_xyz),
                               np.asarray(reference.T_world_object.wxyz_xyz), atol=2e-3)
    np.testing.assert_allclose(np.asarray(estimate.T_object_sensor.wxyz_xyz),
                               np.asarray(reference.sensor_pose(T_world_sensor).wxyz_xyz), atol=2e-3)
    assert estimate.probability_within == pytest.approx(float(reference.probability_within()), abs=1e-4)
    assert estimate.modes and estimate.modes[0][1] <= 1.0 + 1e-6
    # ...and it found the touch (the imprint is in the map).
    assert _symmetric_error(view, maps[1], index, estimate.T_object_sensor, T_true) < 1.0
    assert estimate.as_dict()["grasps"] == 1 and estimate.as_dict()["T_world_object_wxyz_xyz"] is not None


def test_a_background_update_lands_later_with_the_same_belief(live, grasp_frames):
    """With ``background_update`` the settling frame returns before the update (pending); once
    it has run, the next frame reports it (updated) with exactly the belief the synchronous
    update gives; a second grasp waits for the first; nothing recompiles."""
    localizer, maps, _ = live
    settle = localizer.live.settle_frames
    first, second = (grasp_frames(maps[1], int(i), T_WORLD_OBJECT) for i in _grasp_indices(maps[1], 2))

    def two_grasps():
        localizer.reset()
        estimates = []
        for image, opening, T_world_gripper, _ in (first, second):
            estimates += [localizer(image, opening, T_world_gripper) for _ in range(settle)]
            estimates.append(localizer(np.zeros_like(image), opening, T_world_gripper))  # a frame of no touch
        localizer.wait()
        estimates.append(localizer(*first[:3]))
        return estimates

    synchronous = two_grasps()
    localizer.live = dataclasses.replace(localizer.live, background_update=True)
    try:
        with CompilationCounter() as compiles:
            background = two_grasps()
    finally:
        localizer.close()
        localizer.live = dataclasses.replace(localizer.live, background_update=False)
    assert compiles.messages == []
    settling = background[settle - 1]
    assert settling.pending and not settling.updated and settling.grasps == 0
    assert not any(e.pending for e in synchronous)
    assert background[-1].updated and not background[-1].pending and background[-1].grasps == 2
    assert sum(e.updated for e in background) == 2 and sum(e.updated for e in synchronous) == 2
    np.testing.assert_array_equal(background[-1].T_world_object.wxyz_xyz, synchronous[-1].T_world_object.wxyz_xyz)
    assert background[-1].probability_within == synchronous[-1].probability_within


def test_a_map_all_but_ruled_out_drops_out_of_play_until_the_reset(live, grasp_frames):
    """After a grasp, the maps whose P(object) together is at most ``object_tolerance`` are not
    updated again (their P(object) 0) until the reset; with a tolerance of 0 every map is."""
    localizer, maps, _ = live
    grasps = [grasp_frames(maps[1], int(i), T_WORLD_OBJECT) for i in _grasp_indices(maps[1], 2)]
    every = localizer.live
    try:
        for tolerance in (0.0, 0.5):  # 0.5: every map but the gum box's is all but ruled out
            localizer.live = dataclasses.replace(every, object_tolerance=tolerance)
            localizer.reset()
            first = localizer.fuse(*grasps[0][:3])
            second = localizer.fuse(*grasps[1][:3])
            p_cylinder = first.object_probabilities[maps[0].object_id]
            assert first.object_id == maps[1].object_id and 0.0 < p_cylinder < 0.5
            if tolerance == 0.0:
                assert localizer.in_play.all() and [_touches(b) for b in localizer.beliefs] == [2, 2]
                assert second.object_probabilities[maps[0].object_id] > 0.0
            else:
                assert localizer.in_play.tolist() == [False, True]
                assert [_touches(b) for b in localizer.beliefs] == [1, 2]
                assert second.object_probabilities == {maps[0].object_id: 0.0, maps[1].object_id: 1.0}
        localizer.reset()
        assert localizer.in_play.all()
    finally:
        localizer.live = every
        localizer.reset()


def test_a_failed_grasp_reweighs_every_maps_belief_in_play(live, grasp_frames):
    from tactojax.localize.active import ActiveSettings, map_marching_grid, observe_failed_grasp

    localizer, maps, _ = live
    localizer.reset()
    settings = ActiveSettings(hypotheses=2)
    T_world_gripper = grasp_frames(maps[1], int(_grasp_indices(maps[1], 1)[0]), T_WORLD_OBJECT)[2]
    localizer.observe_failed_grasp(T_world_gripper, settings)  # before any touch: nothing to learn
    assert localizer.grasps == 0 and all(not np.isfinite(np.asarray(b.log_weights)).any() for b in localizer.beliefs)
    image, opening, T_world_gripper, _ = grasp_frames(maps[1], int(_grasp_indices(maps[1], 2)[1]), T_WORLD_OBJECT)
    localizer.fuse(image, opening, T_world_gripper)
    before, in_play = list(localizer.beliefs), localizer.in_play.copy()
    localizer.observe_failed_grasp(T_world_gripper, settings)  # the same grasp again, as if it had failed
    assert localizer.grasps == 1 and in_play[localizer.object_ids.index(maps[1].object_id)]
    for m, (prior, posterior, played) in enumerate(zip(before, localizer.beliefs, in_play)):
        view = localizer.stack.map(m)  # the map on its own, not its window of the stack
        expected = observe_failed_grasp(view, map_marching_grid(view), prior, T_world_gripper, settings)
        expected = expected if played else prior  # a map out of play is not updated
        np.testing.assert_allclose(np.asarray(posterior.log_weights), np.asarray(expected.log_weights), atol=1e-5)
    # The grasp closes on the object where the belief puts it: its failure is unlikely under
    # this map, and the map's evidence (P(object)) says so.
    chosen = localizer.object_ids.index(maps[1].object_id)
    assert float(localizer.beliefs[chosen].log_evidence) < float(before[chosen].log_evidence) - 0.5
    localizer.reset()


def test_grasps_without_gripper_poses_start_over(live, grasp_frames):
    localizer, maps, _ = live
    localizer.reset()
    for index in _grasp_indices(maps[1], 2):
        image, opening, _, _ = grasp_frames(maps[1], int(index), T_WORLD_OBJECT)
        estimate = localizer.fuse(image, opening)
        assert estimate.grasps == 1 and estimate.T_object_sensor is not None
        assert [_touches(b) for b in localizer.beliefs] == [1, 1]  # not fused: no kinematics


def test_bad_frames_are_clear_errors(live, grasp_frames):
    localizer, maps, _ = live
    image, opening, T_world_gripper, _ = grasp_frames(maps[0], int(_grasp_indices(maps[0], 1)[0]), T_WORLD_OBJECT)
    localizer.reset()
    with pytest.raises(ValueError, match="uint8 RGB frames"):
        localizer(image[:-1], opening, T_world_gripper)
    with pytest.raises(ValueError, match="uint8 RGB frames"):
        localizer(image.astype(np.float32), opening, T_world_gripper)
    with pytest.raises(ValueError, match="second_image"):
        localizer(image, opening, T_world_gripper, second_image=image[:, :-1])
    for bad in (float("nan"), -3.0):
        with pytest.raises(ValueError, match="opening"):
            localizer(image, bad, T_world_gripper)
    for bad in (np.zeros(6, np.float32), jaxlie.SE3(jnp.full(7, jnp.nan)), T_world_gripper.wxyz_xyz[None]):
        with pytest.raises(ValueError, match="gripper pose"):
            localizer(image, opening, bad)
    assert localizer.grasps == 0 and all(_touches(b) == 0 for b in localizer.beliefs)


def test_a_frame_without_contact_has_no_estimate(live, lookup_model):
    localizer, _, _ = live
    localizer.reset()
    background = _background(lookup_model)
    for frame in (background, np.zeros_like(background)):  # nothing touching; a black frame
        for _ in range(localizer.live.settle_frames + 1):
            estimate = localizer(frame, 40.0)
        assert not estimate.contact and estimate.T_object_sensor is None and estimate.object_id is None
        assert estimate.probability_within == 0.0 and not estimate.updated and estimate.latency_s > 0
        assert estimate.as_dict()["T_object_sensor_wxyz_xyz"] is None
        assert localizer.fuse(frame, 40.0).grasps == 0


@pytest.fixture(scope="module")
def tracker(live_tracker):
    return live_tracker


def test_tracker_starts_from_the_belief_of_a_settled_grasp_then_follows(tracker, lookup_model, grasp_frames):
    tracker, maps, _ = tracker
    localizer = tracker.localizer
    settle = localizer.live.settle_frames
    index = int(np.flatnonzero(np.asarray(maps[1].imprint_valid))[len(maps[1]) // 2])
    image, opening, T_world_gripper, T_true = grasp_frames(maps[1], index, T_WORLD_OBJECT)
    background = np.round(np.asarray(lookup_model.background) * 255).astype(np.uint8)

    tracker.reset()
    relocalizations, tracked_frames = tracker.relocalizations, tracker.tracked_frames
    with CompilationCounter() as compiles:
        settling = [tracker(image, opening, T_world_gripper) for _ in range(settle)]
        assert [e.updated for e in settling] == [False] * (settle - 1) + [True]
        assert not any(e.tracked for e in settling) and tracker.following
        first = settling[-1]  # the belief's best pose, from the localizer
        assert first.object_id == maps[1].object_id and localizer.grasps == 1
        assert tracker.relocalizations == relocalizations + 1
        belief = localizer.beliefs[1]
        followed = [tracker(image, opening, T_world_gripper) for _ in range(2)]  # the same touch: followed
        gone = tracker(background, opening, T_world_gripper)  # contact lost: the track ends, the belief stays
        again = tracker(image, opening, T_world_gripper)  # the next grasp settles anew, from the localizer
    assert compiles.messages == []
    belief_pose = belief.sensor_pose(sensor_pose(T_world_gripper, jnp.float32(opening)))
    np.testing.assert_allclose(np.asarray(first.T_object_sensor.wxyz_xyz), np.asarray(belief_pose.wxyz_xyz), atol=2e-3)
    error = pose_errors(maps[1].points[index], maps[1].valid[index], T_true, followed[-1].T_object_sensor,
                        localizer.stack.map(1).symmetries)["symmetric_rmse"]
    assert float(error) < 1.0
    for estimate in followed:
        assert estimate.tracked and estimate.object_id == first.object_id and not estimate.updated
        assert estimate.probability_within == first.probability_within
        assert estimate.object_probabilities == first.object_probabilities
        moved = np.linalg.norm(np.asarray(estimate.T_object_sensor.translation() - first.T_object_sensor.translation()))
        assert moved < 0.5 and estimate.residual_mm < tracker.tracking.max_residual_mm
        # The object in the world: the followed sensor pose and the gripper's kinematics.
        np.testing.assert_allclose(np.asarray(estimate.T_world_object.translation()),
                                   np.asarray(first.T_world_object.translation()), atol=0.5)
    assert tracker.tracked_frames == tracked_frames + 2
    # A release ends the track, not the belief: the object stays put, the next grasp is fused with it.
    assert not gone.contact and not gone.tracked and not tracker.following
    assert localizer.grasps == 1 and gone.object_id == first.object_id
    np.testing.assert_allclose(np.asarray(gone.T_world_object.wxyz_xyz), np.asarray(first.T_world_object.wxyz_xyz),
                               atol=1e-4)
    assert not again.tracked and not again.updated  # the next grasp settling anew
    assert followed[0].as_dict()["tracked"] is True


def test_tracker_starts_from_a_given_pose_and_checks_it(tracker, grasp_frames):
    tracker, maps, _ = tracker
    index = int(np.flatnonzero(np.asarray(maps[0].imprint_valid))[0])
    image, opening, T_world_gripper, T_true = grasp_frames(maps[0], index, T_WORLD_OBJECT)
    tracker.reset()
    tracker.start(maps[0].object_id, T_true)
    estimate = tracker(image, opening, T_world_gripper)
    assert estimate.tracked and estimate.object_id == maps[0].object_id
    assert np.linalg.norm(np.asarray(estimate.T_object_sensor.translation() - T_true.translation())) < 1.0
    with pytest.raises(ValueError, match="no map of 'banana'"):
        tracker.start("banana", T_true)
    with pytest.raises(ValueError, match="finite"):
        tracker.start(maps[0].object_id, jaxlie.SE3(jnp.full(7, jnp.nan)))


def test_frame_kinematics_on_the_host_match_the_geometry_module():
    """The live loop's host-side pose arithmetic (plain floats) against tactojax.geometry's (JAX, jaxlie)."""
    from tactojax.geometry import opposite_sensor_pose
    from tactojax.localize._localizer import frame_kinematics

    rng = np.random.default_rng(3)
    for _ in range(5):
        gripper, T_world_object, T_object_sensor = (
            jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3(jnp.asarray(q / np.linalg.norm(q), jnp.float32)),
                                                     jnp.asarray(rng.normal(size=3) * 100.0, jnp.float32))
            for q in rng.normal(size=(3, 4)))
        opening = np.float32(rng.uniform(5.0, 80.0))
        got = frame_kinematics(np.asarray(gripper.wxyz_xyz), opening, np.asarray(T_world_object.wxyz_xyz),
                               np.asarray(T_object_sensor.wxyz_xyz))
        T_world_sensor = sensor_pose(gripper, opening)
        expected = (T_world_sensor, opposite_sensor_pose(gripper, opening), T_world_object.inverse() @ T_world_sensor,
                    T_world_sensor @ T_object_sensor.inverse())
        for pose, reference in zip(got, expected):
            assert pose.dtype == np.float32 and pose.shape == (7,)
            np.testing.assert_allclose(pose, np.asarray(reference.wxyz_xyz), atol=2e-4)
